"""``safer-ground rerun``: missions in the rerun viewer, recorded or live.

``safer-ground rerun MISSION.mcap --out mission.rrd``: the MCAP a mission writes
(``ground.recording``, Foxglove schemas) is converted by rerun's own MCAP importer
(``rerun.log_file_from_path``) into a rerun recording file; open it with ``rerun mission.rrd``.

``safer-ground rerun --live``: the live view. It starts rerun's own server (the ``rerun`` program
of the rerun-sdk package) bound to 127.0.0.1: a gRPC endpoint the mission streams to and rerun's
web viewer, a page at ``http://127.0.0.1:WEB_PORT/?url=...``; it prints both and serves until
Ctrl-C. ``safer-hil run --live rerun+http://127.0.0.1:GRPC_PORT/proxy`` then streams the mission
(:class:`LiveSource`, fed by the bench's bus tap beside the MCAP recording): per vehicle, the map
(elevation, north up, unknown dark), the rover and its track, the geofence, the planned stations and
the planner's chosen view with its label, the camera pair and the events, in the project's layout
(:func:`blueprint`).

Exit 2 and one line for a missing or unreadable file or a port in use.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

from fsw.core.map.elevation_map import ElevationMap
from fsw.framework.telemetry import Event
from ground.dictionary import GroundDictionary

HELP = "missions in the rerun viewer: convert a recording (.mcap -> .rrd) or serve the live web view"
APP_ID = "mit_safer"
UNKNOWN_RGB = (40, 40, 48)  # unknown map cells in the live view


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mcap", type=Path, nargs="?", metavar="MISSION.mcap",
                   help="a mission's recording (safer-hil run --out DIR) to convert")
    p.add_argument("--out", type=Path, metavar="RRD", help="rerun recording to write (.rrd)")
    p.add_argument("--live", action="store_true",
                   help="serve the live view on 127.0.0.1 (rerun's web viewer) until Ctrl-C")
    p.add_argument("--grpc-port", type=int, default=9876, help="the port missions stream to (with --live)")
    p.add_argument("--web-port", type=int, default=9090, help="the web page's port (with --live)")
    p.add_argument("--link", metavar="URL", help="with --live: also show what a MAVLink link carries (a real-time "
                                                 "mission: map previews, pose, events, every vehicle), e.g. "
                                                 "udpin:127.0.0.1:14550")


def convert(mcap: Path, out: Path, application_id: str = APP_ID) -> None:
    """Write ``out`` (.rrd) from ``mcap``; ``ValueError`` with the reason if it cannot."""
    import rerun as rr

    with mcap.open("rb") as fh:
        if fh.read(8) != b"\x89MCAP0\r\n":
            raise ValueError(f"{mcap}: not an MCAP file")
    rec = rr.RecordingStream(application_id, recording_id=mcap.stem)
    rec.save(out)
    rec.log_file_from_path(mcap)
    rec.flush()
    rec.disconnect()


# -- the live view ---------------------------------------------------------------------------------
def stream_url(grpc_port: int) -> str:
    return f"rerun+http://127.0.0.1:{grpc_port}/proxy"


def page_url(grpc_port: int, web_port: int) -> str:
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy"


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def start_viewer(grpc_port: int, web_port: int, timeout_s: float = 30.0) -> subprocess.Popen[bytes]:
    """Start rerun's server and web viewer on 127.0.0.1; returns once the gRPC port answers.
    ``ValueError`` when a port is taken, the ``rerun`` program is missing or it does not start."""
    for port in (grpc_port, web_port):
        if not 0 < port < 65536 or not _port_free(port):
            raise ValueError(f"port {port} is in use or out of range")
    exe = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if exe is None:
        raise ValueError("the rerun program (rerun-sdk) is not installed")
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    proc = subprocess.Popen([exe, "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc_port),
                             "--web-viewer-port", str(web_port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True)  # its own group: the wrapper starts the native viewer
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ValueError(f"rerun exited with code {proc.returncode}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", grpc_port)) == 0:
                return proc
        time.sleep(0.1)
    stop_viewer(proc)
    raise ValueError(f"rerun did not open port {grpc_port} within {timeout_s:.0f} s")


def stop_viewer(proc: subprocess.Popen[bytes]) -> None:
    """Stop rerun's server: the ``rerun`` wrapper and the native viewer it started (one process group)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def blueprint(vehicles: tuple[str, ...] = ("recon",)) -> Any:
    """The project's layout: each vehicle's map with the rover and the plan, its cameras, the events."""
    import rerun.blueprint as rrb

    cols = []
    for v in vehicles:
        cols.append(rrb.Horizontal(
            rrb.Spatial2DView(origin=f"/{v}/map", name=f"{v}: map, rover, plan"),
            rrb.Vertical(rrb.Spatial2DView(origin=f"/{v}/camera/left", name=f"{v}: left camera"),
                         rrb.Spatial2DView(origin=f"/{v}/camera/right", name=f"{v}: right camera"),
                         rrb.TextLogView(origin=f"/{v}/events", name=f"{v}: events")),
            column_shares=[3, 2]))
    return rrb.Blueprint(rrb.Vertical(*cols), collapse_panels=True)


def map_rgb(z: np.ndarray) -> np.ndarray:
    """Elevation (row 0 = lowest y, NaN unknown) -> RGB north up: known cells viridis over their
    range, unknown ones dark grey."""
    z = np.asarray(z, np.float64)[::-1]
    known = np.isfinite(z)
    grey = np.zeros(z.shape, np.uint8)
    if known.any():
        lo, hi = float(z[known].min()), float(z[known].max())
        grey[known] = np.round(255 * (z[known] - lo) / (hi - lo if hi > lo else 1.0)).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    rgb[~known] = UNKNOWN_RGB
    return rgb


class LiveSource:
    """One vehicle's entities in a rerun stream (the methods of ``ground.recording.VehicleSource``).

    Map-plane coordinates are image pixels of the north-up map: ``u = (x - x0) / cell``,
    ``v = ny - (y - y0) / cell``; nothing is drawn until the first map gives the grid."""

    def __init__(self, rec: Any, vehicle: str) -> None:
        self.rec, self.vehicle, self.p = rec, vehicle, f"/{vehicle}"
        self.grid: Any = None
        self.scale = 1.0  # image pixels per map cell (1 for the map itself, less for a link's preview)
        self.track: list[tuple[float, float]] = []
        self._pending: list[tuple[str, tuple[Any, ...]]] = []  # what came before the first map gave the grid
        self.last_event: Any = None  # a link's latest event shown (feed_from_link)
        self.seen_images = 0  # a link's complete previews shown
        self.counts = {"map": 0, "pose": 0, "images": 0, "plan": 0, "view": 0, "events": 0}

    def _at(self, t: float) -> None:
        self.rec.set_time("mission_time", duration=float(t))

    def _uv(self, x: float, y: float) -> tuple[float, float]:
        g, k = self.grid, self.scale
        return k * (x - g.x0) / g.cell, k * (g.ny - (y - g.y0) / g.cell)

    def _arrow(self) -> float:
        """Arrow length in image pixels: a twentieth of the map's width, at least 8."""
        return max(8.0, self.scale * self.grid.nx / 20.0)

    def map(self, t: float, emap: ElevationMap) -> None:
        self._draw_map(t, np.where(emap.mapped, emap.z, np.nan), emap.grid)

    def received_map(self, t: float, z: np.ndarray, grid: Any) -> None:
        """A map as an agent received it (heights, NaN unknown; ``grid`` a ``MapGrid``): the Cliff-bot's."""
        self._draw_map(t, z, grid)

    def _draw_map(self, t: float, z: np.ndarray, grid: Any) -> None:
        import rerun as rr

        self.grid, self.scale = grid, 1.0
        self._at(t)
        self.rec.log(f"{self.p}/map/elevation", rr.Image(map_rgb(z)))
        self.counts["map"] += 1
        pending, self._pending = self._pending, []
        for method, args in pending:
            getattr(self, method)(*args)

    def body_pose(self, t: float, x: float, y: float, z: float, yaw: float) -> None:
        """A vehicle without a mast (the Cliff-bot): drawn as :meth:`pose` (``z`` is not drawn)."""
        self.pose(t, SimpleNamespace(x=x, y=y, yaw=yaw))

    def pose(self, t: float, nav: Any) -> None:
        import rerun as rr

        if self.grid is None:
            return
        self._at(t)
        u, v = self._uv(nav.x, nav.y)
        self.track.append((u, v))
        head = self._arrow() * np.array([np.cos(nav.yaw), -np.sin(nav.yaw)])
        self.rec.log(f"{self.p}/map/rover", rr.Arrows2D(origins=[(u, v)], vectors=[head], colors=[(255, 80, 40)],
                                                        radii=1.2, labels=[self.vehicle]))
        self.rec.log(f"{self.p}/map/track", rr.LineStrips2D([self.track[-2000:]], colors=[(255, 160, 120)],
                                                            radii=0.4))
        self.counts["pose"] += 1

    def images(self, t: float, left: np.ndarray, right: np.ndarray) -> None:
        import rerun as rr

        self._at(t)
        for side, img in (("left", left), ("right", right)):
            ok, buf = cv2.imencode(".jpg", np.asarray(img), [cv2.IMWRITE_JPEG_QUALITY, 80])
            if ok:
                self.rec.log(f"{self.p}/camera/{side}",
                             rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))
        self.counts["images"] += 1

    def plan_update(self, t: float, stations: Any, fence: Any, current: int = -1) -> None:
        import rerun as rr

        if self.grid is None:
            self._pending = [p for p in self._pending if p[0] != "plan_update"]
            self._pending.append(("plan_update", (t, stations, fence, current)))
            return
        self._at(t)
        pts = [self._uv(x, y) for x, y, _yaw in stations]
        colours = [(255, 150, 0) if i == current else (50, 150, 255) for i in range(len(pts))]
        self.rec.log(f"{self.p}/map/stations", rr.Points2D(pts, colors=colours, radii=2.0))
        rings = [[self._uv(x, y) for x, y in ring] + [self._uv(*ring[0])] for ring in fence if len(ring) >= 2]
        self.rec.log(f"{self.p}/map/geofence", rr.LineStrips2D(rings, colors=[(255, 30, 30)], radii=0.6))
        self.counts["plan"] += 1

    def chosen_view(self, t: float, x: float, y: float, yaw: float, label: str) -> None:
        import rerun as rr

        if self.grid is None:
            self._pending = [p for p in self._pending if p[0] != "chosen_view"]
            self._pending.append(("chosen_view", (t, x, y, yaw, label)))
            return
        self._at(t)
        u, v = self._uv(x, y)
        self.rec.log(f"{self.p}/map/next_view", rr.Arrows2D(
            origins=[(u, v)], vectors=[1.5 * self._arrow() * np.array([np.cos(yaw), -np.sin(yaw)])],
            colors=[(40, 230, 80)],
            radii=1.5, labels=[label]))
        self.counts["view"] += 1

    def event(self, ev: Event) -> None:
        self.log_line(ev.time_s, ev.severity.name, ev.name, ev.text)

    def log_line(self, t: float, level: Any, name: str, text: str) -> None:
        import rerun as rr

        self._at(t)
        self.rec.log(f"{self.p}/events", rr.TextLog(f"{name}: {text}", level=str(level)))
        self.counts["events"] += 1

    def map_preview(self, t: float, jpeg: bytes, grid: Any = None) -> None:
        """A map preview as the link carries it (JPEG, north up, grey < 8 unknown): drawn as the
        map when ``grid`` (the flight's map grid) says where it lies, else on its own."""
        import rerun as rr

        from fsw.tasks.mavlink_preview import UNKNOWN_BELOW

        self._at(t)
        grey = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if grid is None or grey is None:
            self.rec.log(f"{self.p}/map/preview", rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))
        else:
            self.grid, self.scale = grid, grey.shape[1] / grid.nx
            z = np.where(grey >= UNKNOWN_BELOW, grey.astype(np.float64), np.nan)[::-1]  # map_rgb flips back
            self.rec.log(f"{self.p}/map/elevation", rr.Image(map_rgb(z)))
        self.counts["map"] += 1


def live_stream(url: str, vehicles: tuple[str, ...] = ("recon",), recording_id: str | None = None) -> Any:
    """A rerun recording stream connected to a live view at ``url`` (``rerun+http://127.0.0.1:PORT/proxy``),
    with the project's layout sent."""
    import rerun as rr

    if not url.startswith("rerun+http://127.0.0.1:") and not url.startswith("rerun+http://localhost:"):
        raise ValueError(f"live view {url!r}: expected rerun+http://127.0.0.1:PORT/proxy")
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.connect_grpc(url, default_blueprint=blueprint(vehicles))
    return rec


def feed_from_link(fleet: Any, sources: dict[int, LiveSource], msg: Any, t: float, grid: Any,
                   make: Any) -> None:
    """One MAVLink message into the live view: per vehicle (system id) its pose, events and
    complete map previews; ``make(system_id)`` gives a new vehicle's :class:`LiveSource`."""
    from types import SimpleNamespace

    st = fleet.feed(msg, t)
    if st is None:
        return
    sid = msg.get_srcSystem()
    src = sources.get(sid)
    if src is None:
        src = sources[sid] = make(sid)
    kind = msg.get_type()
    if kind == "LOCAL_POSITION_NED" and st.position_ned is not None:
        n, e, _d = st.position_ned
        src.pose(t, SimpleNamespace(x=n, y=-e, yaw=-(st.yaw_ned or 0.0)))
    elif kind == "STATUSTEXT" and len(st.events) and st.events[-1] is not src.last_event:
        src.last_event = st.events[-1]
        src.log_line(t, _MAV_LEVELS.get(st.events[-1].severity, "INFO"), "", st.events[-1].text)
    elif kind == "ENCAPSULATED_DATA":
        done = [im for im in st.images.images if im.complete]
        for im in done[src.seen_images:]:
            src.map_preview(t, bytes(im.data), grid)
        src.seen_images = len(done)


_MAV_LEVELS = {0: "CRITICAL", 1: "CRITICAL", 2: "CRITICAL", 3: "ERROR", 4: "WARN", 5: "INFO", 6: "INFO", 7: "DEBUG"}


def _stop(*_: object) -> None:
    raise KeyboardInterrupt  # SIGTERM stops the live view as Ctrl-C does: rerun's server with it


def _serve(args: argparse.Namespace, d: GroundDictionary) -> int:
    signal.signal(signal.SIGTERM, _stop)
    link = None
    if args.link:
        from ground.link import GroundLink, LinkError

        try:
            link = GroundLink(args.link, 57600)
        except LinkError as exc:
            print(f"safer-ground rerun: {exc}", file=sys.stderr)
            return 2
    try:
        proc = start_viewer(args.grpc_port, args.web_port)
    except ValueError as exc:
        print(f"safer-ground rerun: {exc}", file=sys.stderr)
        if link is not None:
            link.close()
        return 2
    print(f"live view: {page_url(args.grpc_port, args.web_port)}\n"
          f"stream a mission to it: safer-hil run ... --live {stream_url(args.grpc_port)}"
          + (f"\nshowing the link {args.link}" if link is not None else "") + "\nCtrl-C to stop", flush=True)
    try:
        if link is None:
            return 0 if proc.wait() == 0 else 1
        _follow(link, d, args.grpc_port, proc)
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        if link is not None:
            link.close()
        stop_viewer(proc)


def _follow(link: Any, d: GroundDictionary, grpc_port: int, proc: subprocess.Popen[bytes]) -> None:
    from fsw.core.geometry import MapGrid
    from fsw.settings import load_settings
    from ground.state import Fleet, vehicle_name

    grid = MapGrid.from_config(load_settings(d.source).map)
    fleet, sources = Fleet(d), {}
    rec = live_stream(stream_url(grpc_port), tuple(vehicle_name(i) for i in (1, 2)))
    t0 = time.monotonic()
    while proc.poll() is None:
        msg = link.recv(timeout_s=0.2)
        if msg is not None:
            feed_from_link(fleet, sources, msg, time.monotonic() - t0, grid,
                           lambda sid: LiveSource(rec, vehicle_name(sid)))


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    if args.link and not args.live:
        print("safer-ground rerun: --link goes with --live", file=sys.stderr)
        return 2
    if args.live:
        if args.mcap is not None or args.out is not None:
            print("safer-ground rerun: --live takes no MISSION.mcap or --out", file=sys.stderr)
            return 2
        return _serve(args, d)
    if args.mcap is None or args.out is None:
        print("safer-ground rerun: give MISSION.mcap and --out RRD, or --live", file=sys.stderr)
        return 2
    if args.out.suffix != ".rrd":
        print("safer-ground rerun: --out must name a .rrd file", file=sys.stderr)
        return 2
    try:
        convert(args.mcap, args.out)
    except (OSError, ValueError) as exc:
        print(f"safer-ground rerun: {getattr(exc, 'strerror', None) or exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: rerun recording of {args.mcap} ({args.out.stat().st_size} B); open with: rerun {args.out}")
    return 0
