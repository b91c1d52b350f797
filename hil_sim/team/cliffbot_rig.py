"""The Cliff-bot on its two tethers, on the bench (docs/team.md, "The bench").

:class:`CliffbotRig` holds the true state of the team's hardware: the two Anchorbot winches
(:class:`hil_sim.hw.winch.WinchNode`), the Cliff-bot's wheels and attitude sensor, and the
Cliff-bot's true pose. The pose is quasi-static: after every step the Cliff-bot rests where
both tethers, paid out to the winches' true lengths, are taut on the TRUE ground
(:func:`fsw.core.team.tether_settle.settle` on the truth sampled on the map grid, from the
last pose; where that equilibrium vanished at a step of the face, the nearest one the body
slides or is pulled to, :func:`slide`); its heading
points away from the anchors (the body hangs down the tethers' bisector) and its roll and
pitch follow the ground under it. The rig sets each winch's true tension from the statics.

Every step is judged on the truth and every violation counted (:attr:`violations`):
``tension`` (a tension outside ``[T_min, T_max]``), ``slack`` (the lengths cannot both be
taut: the Cliff-bot would hang on one tether; the pose is kept), ``spool`` (a tether past
its spool), ``tether_on_rock`` (a tether contact on a rock), ``wheel_on_hazard`` (the
footprint on a hazard cell of the truth's ground layers).

The flight side talks to the rig only through CAN frames (:meth:`to_rig`, :meth:`poll`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm.e2e import SequenceChecker
from fsw.comm.rover_can import Bad
from fsw.comm.team.team_can import WINCHES, TeamCan, WheelCommand
from fsw.core.geometry import MapGrid
from fsw.core.localization.landmarks import plate_frames
from fsw.core.localization.localization import LocalizationConfig
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.core.team.standing_plane import surface_normal
from fsw.core.team.tether import TetherConfig, TetherState, anchor_points, height_at, tether_state
from fsw.core.team.tether_settle import settle, settle_many
from hil_sim.faults import FaultInjector
from hil_sim.hw.winch import WinchConfig, WinchNode
from hil_sim.team.team_eval import judge_pose
from hil_sim.world.cliffbot import CliffbotTruth, build_cliffbot, marker_plates
from hil_sim.world.world import World

F64 = NDArray[np.float64]
VIOLATIONS = ("tension", "slack", "spool", "tether_on_rock", "wheel_on_hazard")


@dataclass(frozen=True)
class CliffbotHw:
    wheel_radius_m: float = 0.06
    status_period_s: float = 0.1
    imu_noise_deg: float = 0.2
    wheel_timeout_s: float = 0.5


class CliffbotRig:
    """Winches, the Cliff-bot's body and its true pose on the true ground."""

    def __init__(self, world: World, grid: MapGrid, tcfg: TetherConfig, ccfg: ClimberConfig,
                 wcfg: WinchConfig | None = None, faults: FaultInjector | None = None, seed: int = 0,
                 hw: CliffbotHw | None = None) -> None:
        if world.team is None:
            raise ValueError("the scenario has no team (use a cliff-team scenario)")
        self.world, self.grid, self.tcfg, self.ccfg = world, grid, tcfg, ccfg
        self.hw = hw or CliffbotHw()
        self.faults = faults or FaultInjector(seed)
        self.rng = np.random.default_rng([seed, 2701])
        self.z = world.ground_on_grid(grid)
        self.anchors = anchor_points(self.z, grid, world.team.anchors_xy, tcfg)
        self.truth_ground = ground_layers(self.z, grid, ccfg, anchors=self.anchors)
        self.codec = TeamCan()
        self.xy = np.asarray(world.team.cliffbot_start_xy, float).copy()
        st = tether_state(self.z, grid, self.anchors, self.xy, tcfg, ccfg.footprint_m)
        if st is None:
            raise ValueError("the Cliff-bot's start is not on known ground")
        self.state: TetherState = st
        # the last settle's (lengths, pose) and its answer (_settle)
        self._last_settle: tuple[tuple[tuple[float, float], bytes], tuple[F64, TetherState] | None] | None = None
        w = wcfg or WinchConfig(spool_m=tcfg.spool_m)
        self.winches = {name: WinchNode(name, self.codec, w, st.lengths_m[i], self.faults)
                        for i, name in enumerate(WINCHES)}
        self._set_tensions()
        self.violations = {k: 0 for k in VIOLATIONS}
        self.hazard_cells: set[tuple[int, int]] = set()
        self.path: list[tuple[float, float]] = [(float(self.xy[0]), float(self.xy[1]))]
        self.wheel_rad = [0.0, 0.0]
        self.wheel_cmd = (0.0, 0.0)
        self.wheels_enabled = False
        self.t_wheel_cmd = -math.inf
        self._wheel_seq = SequenceChecker(3, self.hw.wheel_timeout_s)
        self.t_status = -math.inf
        self.counter = 0
        self.now = 0.0
        self.rx_bad = 0
        plates = LocalizationConfig()
        self.plates = marker_plates(plate_frames(self.anchors[0], self.anchors[1], plates), plates.anchor_marker_size_m)

    # -- the true pose ----------------------------------------------------------------------
    def _set_tensions(self) -> None:
        t1, t2 = self.state.statics.tensions_n
        for name, t in zip(WINCHES, (t1, t2), strict=True):
            self.winches[name].tension_n = max(0.0, t) if math.isfinite(t) else 0.0

    @property
    def yaw(self) -> float:
        """Heading: away from the anchors (the body hangs down the bisector of its tethers)."""
        p = self.state.paths[0].pull + self.state.paths[1].pull
        return math.atan2(-p[1], -p[0]) if math.hypot(p[0], p[1]) > 1e-6 else -math.pi / 2

    def attitude_deg(self) -> tuple[float, float, float]:
        """True roll, pitch (nose up +) and yaw of the body on the ground under it."""
        n = surface_normal(self.z, self.grid, self.xy, self.ccfg.footprint_m)
        yaw = self.yaw
        if n is None:
            return 0.0, 0.0, math.degrees(yaw)
        fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        pitch = math.degrees(math.asin(max(-1.0, min(1.0, -float(n @ fwd)))))
        roll = math.degrees(math.asin(max(-1.0, min(1.0, float(n @ left)))))
        return roll, pitch, math.degrees(yaw)

    def cliffbot_truth(self) -> CliffbotTruth:
        """The world's Cliff-bot body at the true pose (for the renderer), standing on the ground
        under it: tilted by the roll and pitch its attitude sensor measures (without the noise)."""
        cb = self.world.cliffbot
        zg = float(self.world.ground_at(float(self.xy[0]), float(self.xy[1])))
        roll, pitch, _ = self.attitude_deg()
        return build_cliffbot(float(self.xy[0]), float(self.xy[1]), zg, self.yaw,
                              size_m=(cb.length_m, cb.width_m, cb.height_m),
                              marker_size_m=cb.markers[0].size_m if cb.markers else 0.18,
                              roll=math.radians(roll), pitch=math.radians(pitch))

    def world_now(self) -> World:
        """The world as the RECON-bot's cameras see it now: the Cliff-bot where it stands, and the
        Anchorbots' marker plates (the as-built ``[localization]`` defaults, docs/algorithm.md §5.2)."""
        return dataclasses.replace(self.world, cliffbot=self.cliffbot_truth(), props=self.plates)

    # -- frames -----------------------------------------------------------------------------
    def to_rig(self, frames: list[tuple[int, bytes]], now: float) -> None:
        wheel_id = self.codec.frame_id("CB_WHEELS_CMD")
        for fid, data in frames:
            if fid == wheel_id:
                d = self.codec.decode(fid, data, epoch=None)
                if isinstance(d, Bad) or not isinstance(d, WheelCommand):
                    self.rx_bad += 1
                    continue
                if self._wheel_seq.check_frame(self.codec.e2e[fid], bytes(data), now)[0].accepted:
                    self.wheel_cmd, self.wheels_enabled, self.t_wheel_cmd = (d.left_radps, d.right_radps), d.enable, now
                continue
            for w in self.winches.values():
                w.on_frame(fid, data, now)

    def poll(self, now: float) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        for w in self.winches.values():
            out += w.poll(now)
        if now - self.t_status >= self.hw.status_period_s - 1e-9:
            self.t_status = now
            self.counter += 1
            out.append(self.codec.wheel_status(self.wheel_rad[0], self.wheel_rad[1], self.wheels_enabled, self.counter))
            roll, pitch, yaw = self.attitude_deg()
            noise = self.hw.imu_noise_deg * self.rng.standard_normal(3)
            out.append(self.codec.attitude(roll + noise[0], pitch + noise[1], yaw + noise[2], self.counter))
        return out

    # -- physics ----------------------------------------------------------------------------
    def step(self, dt: float, now: float) -> None:
        """Winches move, the Cliff-bot settles on the true ground, violations are judged."""
        self.now = now
        self.faults.update(now)
        for w in self.winches.values():
            w.step(dt, now)
        lengths = (self.winches["WINCH_A"].paid_out_m, self.winches["WINCH_B"].paid_out_m)
        if max(lengths) > self.tcfg.spool_m:
            self.violations["spool"] += 1
        got = self._settle(lengths)
        if got is None:
            self.violations["slack"] += 1
        else:
            old, old_z = self.xy, height_at(self.z, self.grid, self.xy)
            self.xy, self.state = got
            step = self.xy - old
            if float(np.linalg.norm(step)) > 0:
                self.path.append((float(self.xy[0]), float(self.xy[1])))
                # The wheels roll the distance along the ground, forward or back along the heading.
                dz = height_at(self.z, self.grid, self.xy) - old_z
                along = math.sqrt(float(step @ step) + (dz * dz if math.isfinite(dz) else 0.0))
                sign = 1.0 if step @ np.array([math.cos(self.yaw), math.sin(self.yaw)]) >= 0 else -1.0
                r = self.hw.wheel_radius_m
                self.wheel_rad = [w + sign * along / r for w in self.wheel_rad]
            self._set_tensions()
            self._judge()

    def _settle(self, lengths: tuple[float, float]) -> tuple[F64, TetherState] | None:
        """Where the tethers at ``lengths`` hold the Cliff-bot, from its pose (``settle``). On
        the rig's fixed ground, anchors and tethers that is a function of the lengths and the
        pose alone, and a Cliff-bot at rest (waiting for the map, sensing, planning: most of
        its frames) asks the same question every frame: the last answer is given again."""
        key = (lengths, self.xy.tobytes())
        if self._last_settle is None or self._last_settle[0] != key:
            held = self._last_settle is None or self._last_settle[1] is not None
            got = settle(self.z, self.grid, self.anchors, lengths, self.xy, self.tcfg)
            if got is None and held:
                got = slide(self.z, self.grid, self.anchors, lengths, self.xy, self.tcfg)
            self._last_settle = (key, got)
        got = self._last_settle[1]
        return None if got is None else (got[0].copy(), got[1])

    def _judge(self) -> None:
        found, cell = judge_pose(self.state, self.xy, self.truth_ground, self.grid, self.tcfg, self.ccfg)
        for kind in found:
            self.violations[kind] += 1
        if cell is not None:
            self.hazard_cells.add(cell)


SLIDE_RADII_M = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5)  # where :func:`slide` looks from, round the last pose
SLIDE_AZIMUTHS = 12


def slide(z: F64, grid: MapGrid, anchors: F64, lengths: tuple[float, float], xy: F64,
          cfg: TetherConfig) -> tuple[F64, TetherState] | None:
    """Where the body goes when the equilibrium it rested in vanishes (:func:`settle` from its
    last pose finds none): the lengths moved past a fold of the statics, at a step of the face,
    and the body slides down it (tethers paid out) or is pulled up over it (tethers hauled in) to
    the nearest place where both tethers are taut at ``lengths``. The search settles from rings
    round the last pose (``SLIDE_RADII_M``, ``SLIDE_AZIMUTHS`` guesses each, one
    :func:`~fsw.core.team.tether_settle.settle_many` batch) and keeps the settled place nearest
    the last pose. None when none lies within the largest ring: the tethers cannot both be taut
    there (slack; a taut place farther off is a fall, not a slide)."""
    a = 2.0 * math.pi * np.arange(SLIDE_AZIMUTHS) / SLIDE_AZIMUTHS
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    guesses = np.concatenate([np.asarray(xy, float) + r * ring for r in SLIDE_RADII_M])
    got = settle_many(z, grid, anchors, np.tile(np.asarray(lengths, float), (len(guesses), 1)), guesses, cfg)
    far = SLIDE_RADII_M[-1]  # a taut place farther off is a fall, not a slide
    found = [(float(np.hypot(*(p[0] - xy))), p) for p in got.places if p is not None]
    near = [f for f in found if f[0] <= far]
    return min(near, key=lambda f: f[0])[1] if near else None
