"""Mission recordings for Foxglove (MCAP with its well-known schemas), written on the ground side.

The recorder never runs inside the flight executive's tasks: the bench's :class:`BusTap` reads
the software bus and the event log between frames and logs what it saw (it only adds mailboxes
on the bus and a listener on the event log); a ground tool feeds it from a .tlog. One
:class:`MissionRecorder` is one MCAP file; each vehicle is one :class:`VehicleSource` whose
topics start with ``/<vehicle>/`` and whose frames are ``<vehicle>/base_link`` and
``<vehicle>/mast`` under the shared ``map`` frame, so a second agent is a second source.

Topics of a source ``recon`` (Foxglove schema in brackets):

- ``/recon/map/elevation``, ``/recon/map/variance``, ``/recon/map/interest`` (``foxglove.Grid``,
  float32, NaN unknown; row 0 = lowest y, as the flight map, in the ``map`` frame)
- ``/tf`` (``foxglove.FrameTransforms``: ``map -> recon/base_link`` (x, y, z, roll, pitch, yaw),
  ``recon/base_link -> recon/mast`` (pan, tilt, lift))
- ``/recon/camera/left``, ``/recon/camera/right`` (``foxglove.CompressedImage``, PNG)
- ``/recon/plan`` (``foxglove.SceneUpdate``: planned stations as cubes, the geofence as lines)
- ``/recon/view`` (``foxglove.SceneUpdate``: the chosen next view as an arrow)
- ``/recon/events`` (``foxglove.Log``)

A team mission's Cliff-bot is the source ``cliffbot`` (:class:`CliffbotTap`): the map it
received on ``/cliffbot/map/elevation``, ``map -> cliffbot/base_link`` (its navigation estimate)
on ``/tf``, its events on ``/cliffbot/events``.

Log times are mission seconds (the executive's clock), so a lockstep recording is the same for
the same seed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import foxglove
import numpy as np
from foxglove import channels as fc
from foxglove import messages as fm

from fsw.core.map.elevation_map import ElevationMap
from fsw.framework.telemetry import Event, Severity
from fsw.tasks.messages import CAMERA_FRAME, MAP_UPDATED, NAV_POSE, NBV_RESULT

MAP_LAYERS = ("elevation", "variance", "interest")
_LEVELS = {Severity.FATAL: fm.LogLevel.Fatal, Severity.WARNING_HI: fm.LogLevel.Error,
           Severity.WARNING_LO: fm.LogLevel.Warning, Severity.COMMAND: fm.LogLevel.Info,
           Severity.ACTIVITY_HI: fm.LogLevel.Info, Severity.ACTIVITY_LO: fm.LogLevel.Info,
           Severity.DIAGNOSTIC: fm.LogLevel.Debug}


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


def _stamp(t: float) -> fm.Timestamp:
    ns = _ns(t)
    return fm.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _quat(roll: float, pitch: float, yaw: float) -> fm.Quaternion:
    """ZYX (yaw, pitch, roll) Euler angles to a quaternion."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return fm.Quaternion(x=sr * cp * cy - cr * sp * sy, y=cr * sp * cy + sr * cp * sy,
                         z=cr * cp * sy - sr * sp * cy, w=cr * cp * cy + sr * sp * sy)


def _colour(r: float, g: float, b: float, a: float = 1.0) -> fm.Color:
    return fm.Color(r=r, g=g, b=b, a=a)


def _point(x: float, y: float, z: float = 0.0) -> fm.Point3:
    return fm.Point3(x=float(x), y=float(y), z=float(z))


class MissionRecorder:
    """One MCAP file; :meth:`source` gives the per-vehicle logger."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.context = foxglove.Context()
        self._writer = foxglove.open_mcap(self.path, allow_overwrite=True, context=self.context)
        self.tf = fc.FrameTransformsChannel("/tf", context=self.context)
        self.sources: dict[str, VehicleSource] = {}

    def source(self, vehicle: str) -> VehicleSource:
        if vehicle not in self.sources:
            self.sources[vehicle] = VehicleSource(self, vehicle)
        return self.sources[vehicle]

    def close(self) -> None:
        self._writer.close()


class VehicleSource:
    """The topics of one vehicle in a :class:`MissionRecorder`."""

    def __init__(self, rec: MissionRecorder, vehicle: str) -> None:
        ctx, p = rec.context, f"/{vehicle}"
        self.rec, self.vehicle = rec, vehicle
        self.base, self.mast = f"{vehicle}/base_link", f"{vehicle}/mast"
        self.grids = {name: fc.GridChannel(f"{p}/map/{name}", context=ctx) for name in MAP_LAYERS}
        self.cameras = {side: fc.CompressedImageChannel(f"{p}/camera/{side}", context=ctx)
                        for side in ("left", "right")}
        self.plan = fc.SceneUpdateChannel(f"{p}/plan", context=ctx)
        self.view = fc.SceneUpdateChannel(f"{p}/view", context=ctx)
        self.log = fc.LogChannel(f"{p}/events", context=ctx)
        self._preview: Any = None  # /<vehicle>/map/preview, made when a tlog's preview arrives
        self.counts = {"map": 0, "pose": 0, "images": 0, "plan": 0, "view": 0, "events": 0}

    def map(self, t: float, emap: ElevationMap) -> None:
        g = emap.grid
        mapped = emap.mapped
        layers = {"elevation": emap.z, "variance": emap.var, "interest": emap.interest}
        pose = fm.Pose(position=fm.Vector3(x=g.x0, y=g.y0, z=0.0), orientation=fm.Quaternion(w=1.0))
        field = fm.PackedElementFieldNumericType.Float32
        for name, arr in layers.items():
            a = np.where(mapped, arr, np.nan) if name != "interest" else np.asarray(arr)
            data = np.ascontiguousarray(a, dtype="<f4")
            self.grids[name].log(fm.Grid(
                timestamp=_stamp(t), frame_id="map", pose=pose, column_count=g.nx,
                cell_size=fm.Vector2(x=g.cell, y=g.cell), row_stride=4 * g.nx, cell_stride=4,
                fields=[fm.PackedElementField(name=name, offset=0, type=field)], data=data.tobytes()),
                log_time=_ns(t))
        self.counts["map"] += 1

    def pose(self, t: float, nav: Any) -> None:
        """``nav``: a ``NavPose`` (x, y, yaw, roll, pitch, z_m, joints = pan, tilt, lift)."""
        pan, tilt, lift = (float(v) for v in nav.joints)
        self.rec.tf.log(fm.FrameTransforms(transforms=[
            fm.FrameTransform(timestamp=_stamp(t), parent_frame_id="map", child_frame_id=self.base,
                              translation=fm.Vector3(x=nav.x, y=nav.y, z=nav.z_m),
                              rotation=_quat(nav.roll, nav.pitch, nav.yaw)),
            fm.FrameTransform(timestamp=_stamp(t), parent_frame_id=self.base, child_frame_id=self.mast,
                              translation=fm.Vector3(x=0.0, y=0.0, z=lift),
                              rotation=_quat(0.0, -tilt, pan)),
        ]), log_time=_ns(t))
        self.counts["pose"] += 1

    def received_map(self, t: float, z: np.ndarray, grid: Any) -> None:
        """A map as an agent received it (heights only, NaN unknown; ``grid`` a ``MapGrid``):
        ``/<vehicle>/map/elevation``."""
        pose = fm.Pose(position=fm.Vector3(x=grid.x0, y=grid.y0, z=0.0), orientation=fm.Quaternion(w=1.0))
        data = np.ascontiguousarray(z, dtype="<f4")
        self.grids["elevation"].log(fm.Grid(
            timestamp=_stamp(t), frame_id="map", pose=pose, column_count=grid.nx,
            cell_size=fm.Vector2(x=grid.cell, y=grid.cell), row_stride=4 * grid.nx, cell_stride=4,
            fields=[fm.PackedElementField(name="elevation", offset=0, type=fm.PackedElementFieldNumericType.Float32)],
            data=data.tobytes()), log_time=_ns(t))
        self.counts["map"] += 1

    def body_pose(self, t: float, x: float, y: float, z: float, yaw: float) -> None:
        """``map -> <vehicle>/base_link`` for a vehicle without a mast (the Cliff-bot)."""
        self.rec.tf.log(fm.FrameTransforms(transforms=[fm.FrameTransform(
            timestamp=_stamp(t), parent_frame_id="map", child_frame_id=self.base,
            translation=fm.Vector3(x=x, y=y, z=z), rotation=_quat(0.0, 0.0, yaw))]), log_time=_ns(t))
        self.counts["pose"] += 1

    def images(self, t: float, left: np.ndarray, right: np.ndarray) -> None:
        for side, img in (("left", left), ("right", right)):
            ok, buf = cv2.imencode(".png", np.asarray(img))
            if not ok:
                continue
            self.cameras[side].log(fm.CompressedImage(timestamp=_stamp(t), frame_id=self.mast,
                                                      data=buf.tobytes(), format="png"), log_time=_ns(t))
        self.counts["images"] += 1

    def plan_update(self, t: float, stations: Any, fence: Any, current: int = -1) -> None:
        cubes = [fm.CubePrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=0.05), orientation=_quat(0, 0, yaw)),
                                  size=fm.Vector3(x=0.2, y=0.1, z=0.1),
                                  color=_colour(1.0, 0.6, 0.0) if i == current else _colour(0.2, 0.6, 1.0))
                 for i, (x, y, yaw) in enumerate(stations)]
        lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, thickness=0.03,
                                  points=[_point(x, y, 0.02) for x, y in ring], color=_colour(1.0, 0.1, 0.1))
                 for ring in fence if len(ring) >= 2]
        self.plan.log(fm.SceneUpdate(entities=[
            fm.SceneEntity(timestamp=_stamp(t), frame_id="map", id=f"{self.vehicle}/stations", cubes=cubes),
            fm.SceneEntity(timestamp=_stamp(t), frame_id="map", id=f"{self.vehicle}/geofence", lines=lines),
        ]), log_time=_ns(t))
        self.counts["plan"] += 1

    def chosen_view(self, t: float, x: float, y: float, yaw: float, label: str) -> None:
        arrow = fm.ArrowPrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=0.1), orientation=_quat(0, 0, yaw)),
                                  shaft_length=0.3, shaft_diameter=0.04, head_length=0.1, head_diameter=0.1,
                                  color=_colour(0.1, 0.9, 0.3))
        text = fm.TextPrimitive(pose=fm.Pose(position=fm.Vector3(x=x, y=y, z=0.3), orientation=fm.Quaternion(w=1.0)),
                                billboard=True, font_size=14.0, scale_invariant=True,
                                color=_colour(1, 1, 1), text=label)
        self.view.log(fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=_stamp(t), frame_id="map", id=f"{self.vehicle}/next_view", arrows=[arrow], texts=[text])]),
            log_time=_ns(t))
        self.counts["view"] += 1

    def event(self, ev: Event) -> None:
        self.log_line(ev.time_s, _LEVELS.get(ev.severity, fm.LogLevel.Unknown), ev.name, ev.text)

    def log_line(self, t: float, level: Any, name: str, text: str) -> None:
        self.log.log(fm.Log(timestamp=_stamp(t), level=level, message=text, name=name), log_time=_ns(t))
        self.counts["events"] += 1

    def map_preview(self, t: float, jpeg: bytes) -> None:
        """A map preview as the ground received it (JPEG, north up): ``/<vehicle>/map/preview``."""
        if self._preview is None:
            self._preview = fc.CompressedImageChannel(f"/{self.vehicle}/map/preview", context=self.rec.context)
        self._preview.log(fm.CompressedImage(timestamp=_stamp(t), frame_id="map", data=jpeg, format="jpeg"),
                          log_time=_ns(t))
        self.counts["map"] += 1


class BusTap:
    """Feed ``source`` (and each of ``mirrors``: a live view, ``ground.rerun_cli.LiveSource``, with
    the same methods) from executive ``exe``; poses at most every ``pose_period_s`` of mission time."""

    def __init__(self, exe: Any, source: VehicleSource, pose_period_s: float = 0.2,
                 mirrors: tuple[Any, ...] = ()) -> None:
        bus, name = exe.bus, f"recorder.{source.vehicle}"
        self.exe, self.source, self.pose_period_s = exe, source, pose_period_s
        self.sinks: tuple[Any, ...] = (source, *mirrors)
        self.maps = bus.subscribe(MAP_UPDATED, name, depth=4)
        self.poses = bus.subscribe(NAV_POSE, name, depth=1)
        self.frames = bus.subscribe(CAMERA_FRAME, name, depth=4)
        self.views = bus.subscribe(NBV_RESULT, name, depth=4)
        self.plans = bus.subscribe(exe.ctx.cfg.mavlink.plan_topic, name, depth=4)
        self._events: list[Event] = []
        exe.events.listeners.append(self._events.append)
        self._next_pose_s = 0.0

    def poll(self) -> None:
        now = float(self.exe.ctx.clock.now())
        maps, frames = self.maps.drain(), self.frames.drain()
        views = [v for v in self.views.drain() if v is not None]
        plans = self.plans.drain()
        nav = self.poses.latest()
        if nav is not None and now >= self._next_pose_s:
            self._next_pose_s = now + self.pose_period_s
        else:
            nav = None
        events, self._events[:] = list(self._events), []
        for src in self.sinks:
            for up in maps:
                src.map(up.time_s, up.snapshot)
            if nav is not None:
                src.pose(now, nav)
            for fr in frames:
                src.images(fr.time_s, fr.left, fr.right)
            for view in views:
                x, y, yaw = view.rover
                src.chosen_view(now, x, y, yaw, f"{view.method} {view.expected_new_cells:.0f} cells")
            for plan in plans:
                src.plan_update(now, plan.stations, plan.fence, plan.current)
            for ev in events:
                src.event(ev)

    def close(self) -> None:
        if self._events.append in self.exe.events.listeners:
            self.exe.events.listeners.remove(self._events.append)


class CliffbotTap:
    """Feed ``source`` from the Cliff-bot's executive ``exe``: every map its radio delivered
    (``cliffbot.map``) as ``/<vehicle>/map/elevation``, its navigation estimate (the navigation
    task's ``x_m``, ``y_m``, ``yaw_deg``; height from the received map) on ``/tf`` at most every
    ``pose_period_s``, and its events; each of ``mirrors`` (a live view, ``ground.rerun_cli.LiveSource``)
    is fed the same."""

    def __init__(self, exe: Any, source: VehicleSource, pose_period_s: float = 0.2, nav: str = "cb_nav",
                 mirrors: tuple[Any, ...] = ()) -> None:
        from fsw.core.geometry import MapGrid
        from fsw.tasks.cliffbot.messages import CB_MAP

        self.exe, self.source, self.pose_period_s, self.nav = exe, source, pose_period_s, nav
        self.sinks: tuple[Any, ...] = (source, *mirrors)
        self.grid = MapGrid.from_config(exe.ctx.cfg.map)
        self.maps = exe.bus.subscribe(CB_MAP, f"recorder.{source.vehicle}", depth=4)
        self._z: np.ndarray | None = None
        self._events: list[Event] = []
        exe.events.listeners.append(self._events.append)
        self._next_pose_s = 0.0

    def poll(self) -> None:
        now = float(self.exe.ctx.clock.now())
        for got in self.maps.drain():
            self._z = np.asarray(got.z, np.float32)
            for src in self.sinks:
                src.received_map(now, self._z, self.grid)
        tm = self.exe.telemetry
        names = [f"{self.nav}.{c}" for c in ("x_m", "y_m", "yaw_deg")]
        if now >= self._next_pose_s and all(n in tm.values for n in names):
            x, y, yaw_deg = (tm.get(n) for n in names)
            if None not in (x, y, yaw_deg):
                self._next_pose_s = now + self.pose_period_s
                z = self._height(float(x), float(y))
                for src in self.sinks:
                    src.body_pose(now, float(x), float(y), z, math.radians(float(yaw_deg)))
        events, self._events[:] = list(self._events), []
        for src in self.sinks:
            for ev in events:
                src.event(ev)

    def _height(self, x: float, y: float) -> float:
        g = self.grid
        ix, iy = int((x - g.x0) // g.cell), int((y - g.y0) // g.cell)
        if self._z is None or not (0 <= ix < g.nx and 0 <= iy < g.ny) or not np.isfinite(self._z[iy, ix]):
            return 0.0
        return float(self._z[iy, ix])

    def close(self) -> None:
        if self._events.append in self.exe.events.listeners:
            self.exe.events.listeners.remove(self._events.append)
