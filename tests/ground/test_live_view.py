"""Issue 29, item 4 (the live view) and item 1 (the map preview is the codec's reduced map).

The live view is rerun's web viewer served on 127.0.0.1 (``safer-ground rerun --live``); a mission
streams to it through :class:`ground.rerun_cli.LiveSource`. The browser test loads the page in
headless Chromium and checks that the map's colours are on screen."""

from __future__ import annotations

import shutil
import socket
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from fsw.core.codec.mapcodec import CodecConfig, decode_map, encode_map
from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.tasks.mavlink_preview import PreviewError, encode_preview, reduce_map
from ground import rerun_cli


def _terrain_map(n: int = 64) -> ElevationMap:
    emap = ElevationMap(MapGrid(0.0, 0.0, 0.03, n, n))
    yy, xx = np.mgrid[0:n, 0:n]
    z = 0.02 * np.sin(xx / 5.0) + 0.01 * np.cos(yy / 3.0)
    z[(xx - n / 2) ** 2 + (yy - n / 2) ** 2 > (0.4 * n) ** 2] = np.nan  # a mapped disc, unknown around
    emap.z = z
    emap.var = np.where(np.isfinite(z), 1e-4, np.inf)
    emap.n = np.isfinite(z).astype(np.int32)
    return emap


def test_the_preview_is_the_codecs_decode_of_the_map() -> None:
    emap = _terrain_map()
    codec = CodecConfig()
    reduced, nbytes = reduce_map(emap, wheel_diameter_m=0.12, codec=codec)
    enc = encode_map(np.asarray(emap.z, np.float32), cell_m=0.03, wheel_diameter_m=0.12, cfg=codec)
    assert nbytes == len(enc.data) > 0
    assert np.array_equal(np.asarray(reduced), decode_map(enc.data).z, equal_nan=True)
    z = np.asarray(emap.z)
    r = np.asarray(reduced, np.float64)
    # the codec keeps what is unknown unknown and stays within its realised error
    assert np.array_equal(np.isfinite(r), np.isfinite(z))
    assert np.nanmax(np.abs(r - z)) <= enc.max_error_m + 1e-6
    # the MapUpdate carrying the map gives the same preview, a bare array passes unchanged
    same, _ = reduce_map(SimpleNamespace(snapshot=emap), wheel_diameter_m=0.12, codec=codec)
    assert np.array_equal(np.asarray(same), r, equal_nan=True)
    raw = np.zeros((4, 4), np.uint8)
    assert reduce_map(raw, wheel_diameter_m=0.12, codec=codec) == (raw, 0)
    jpeg, w, h = encode_preview(reduced, 32, 60)
    assert (w, h) == (32, 32) and cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE) is not None


def test_an_unmapped_map_previews_without_the_codec_and_a_refusal_is_one_reason() -> None:
    emap = ElevationMap(MapGrid(0.0, 0.0, 0.03, 8, 8))
    z, nbytes = reduce_map(emap, wheel_diameter_m=0.12, codec=CodecConfig())
    assert nbytes == 0 and not np.isfinite(np.asarray(z)).any()
    with pytest.raises(PreviewError, match="map codec"):
        reduce_map(_terrain_map(16), wheel_diameter_m=0.12, codec=CodecConfig(max_cells=16))


def test_live_map_colours_unknown_dark_and_puts_north_up() -> None:
    z = np.full((4, 3), np.nan)
    z[0, :] = 0.0  # the lowest row of the map (south) ...
    z[3, :] = 1.0
    rgb = rerun_cli.map_rgb(z)
    assert rgb.shape == (4, 3, 3) and tuple(rgb[1, 1]) == rerun_cli.UNKNOWN_RGB
    assert tuple(rgb[3, 0]) != tuple(rgb[0, 0])  # ... is drawn at the bottom, north (high) at the top
    assert rgb[0, 0].tolist() == rgb[0, 2].tolist()


class _Rec:
    """A rerun stream stand-in that keeps what was logged."""

    def __init__(self) -> None:
        self.logged: list[tuple[str, object]] = []
        self.times: list[float] = []

    def set_time(self, timeline: str, duration: float) -> None:
        self.times.append(duration)

    def log(self, path: str, entity: object) -> None:
        self.logged.append((path, entity))


def test_live_source_draws_in_map_pixels_and_keeps_the_plan_until_the_grid_is_known() -> None:
    rec = _Rec()
    src = rerun_cli.LiveSource(rec, "recon")
    src.plan_update(0.5, [(0.3, 0.6, 0.0)], [[(0.0, 0.0), (0.3, 0.0), (0.3, 0.3)]])
    src.chosen_view(0.6, 0.3, 0.6, 0.0, "5 10 cells")
    assert rec.logged == []  # no grid yet: nothing can be placed
    src.map(1.0, _terrain_map(32))  # cell 0.03 m, origin (0, 0), 32 x 32
    paths = [p for p, _ in rec.logged]
    assert paths == ["/recon/map/elevation", "/recon/map/stations", "/recon/map/geofence", "/recon/map/next_view"]
    assert src._uv(0.3, 0.6) == pytest.approx((10.0, 12.0))  # u = x / cell, v = ny - y / cell (north up)
    src.pose(2.0, SimpleNamespace(x=0.3, y=0.6, yaw=0.0))
    assert [p for p, _ in rec.logged[-2:]] == ["/recon/map/rover", "/recon/map/track"] and rec.times[-1] == 2.0


def test_live_refuses_a_non_local_url_and_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    from ground.cli import main as ground_main

    with pytest.raises(ValueError, match="127.0.0.1"):
        rerun_cli.live_stream("rerun+http://10.0.0.1:9876/proxy")
    assert ground_main(["rerun", "--live", "--out", "x.rrd"]) == 2
    assert ground_main(["rerun"]) == 2
    assert "--live" in capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _map_on_screen(img: np.ndarray) -> bool:
    """The map's viridis colours (not the viewer's greys) cover a good part of the page: its high
    (yellow-green) and its low (blue-purple) end both."""
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    coloured = (hsv[..., 1] > 120) & (hsv[..., 2] > 60)
    high = (hsv[..., 0] > 20) & (hsv[..., 0] < 45) & coloured
    low = (hsv[..., 0] > 100) & (hsv[..., 0] < 150) & coloured
    return bool(coloured.mean() > 0.03 and high.any() and low.any())


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.skipif(shutil.which("chromium") is None, reason="headless Chromium not installed (apt install chromium)")
def test_the_live_page_shows_the_map_in_headless_chromium(tmp_path: Path) -> None:
    from tests.support.headless import HeadlessChromium

    grpc, web = _free_port(), _free_port()
    proc = rerun_cli.start_viewer(grpc, web)
    try:
        rec = rerun_cli.live_stream(rerun_cli.stream_url(grpc), recording_id="test")
        src = rerun_cli.LiveSource(rec, "recon")
        src.map(1.0, _terrain_map(96))
        src.pose(1.0, SimpleNamespace(x=1.4, y=1.4, yaw=0.5))
        src.chosen_view(1.0, 1.8, 1.6, 1.0, "5 120 cells")
        rec.flush()
        with HeadlessChromium(window=(1200, 800)) as browser:
            browser.open(rerun_cli.page_url(grpc, web))
            first = browser.screenshot()
            assert not _map_on_screen(first)  # the page starts without it (the check can fail)
            img = browser.wait_for(_map_on_screen, timeout_s=200)
            cv2.imwrite(str(tmp_path / "live.png"), img)
            assert img is not None, "the map never appeared on the live page"
    finally:
        rerun_cli.stop_viewer(proc)


def test_a_real_time_mission_reaches_the_live_view_from_its_link() -> None:
    """``safer-ground rerun --live --link URL``: what the link carries (previews drawn as the map
    where the flight's grid puts them, the rover over them, events), per vehicle."""
    from fsw.comm.mavlink_dialect import mavlink, new_codec
    from fsw.comm.mavlink_image import ImageSender
    from fsw.comm.mavlink_telemetry import heartbeat, statustext
    from fsw.framework.telemetry import Severity
    from ground.dictionary import load_dictionary
    from ground.state import Fleet, vehicle_name

    grid = MapGrid(0.0, 0.0, 0.03, 64, 64)
    rover, rx = new_codec(1, 1), new_codec(250, 1)
    frames = [heartbeat("MOVE", False, False).pack(rover)]
    grey = np.full((32, 32), 120, np.uint8)
    sender = ImageSender()
    sender.offer(cv2.imencode(".jpg", grey)[1].tobytes(), 32, 32, mavlink.MAVLINK_DATA_STREAM_IMG_JPEG, 90)
    while (m := sender.peek()) is not None:
        frames.append(m.pack(rover))
        sender.consume()
    frames.append(rover.local_position_ned_encode(1000, 0.96, -0.96, 0.0, 0, 0, 0).pack(rover))  # x 0.96, y 0.96
    frames += [m.pack(rover) for m in statustext(Severity.ACTIVITY_HI, "mission.STATE: mission MOVE", 0)]
    rec, fleet, sources = _Rec(), Fleet(load_dictionary()), {}

    def make(sid: int) -> rerun_cli.LiveSource:
        return rerun_cli.LiveSource(rec, vehicle_name(sid))

    for f in frames:
        for msg in rx.parse_buffer(f) or []:
            rerun_cli.feed_from_link(fleet, sources, msg, 1.0, grid, make)
    paths = [p for p, _ in rec.logged]
    assert paths[0] == "/recon/map/elevation" and "/recon/map/rover" in paths and paths[-1] == "/recon/events"
    src = sources[1]
    assert src.scale == 0.5 and src._uv(0.96, 0.96) == pytest.approx((16.0, 16.0))  # the preview's pixels


def test_a_team_missions_cliffbot_reaches_the_live_view_as_it_reaches_the_recording() -> None:
    """Issue 29: the Cliff-bot's tap feeds the live view (a mirror) what it records: the received
    map, its pose on that map and its events, under ``/cliffbot``."""
    from fsw.framework.telemetry import Event, Severity
    from ground.recording import CliffbotTap

    z = np.asarray(_terrain_map(32).z, np.float32)
    maps = [[SimpleNamespace(z=z)]]
    sub = SimpleNamespace(drain=lambda: maps.pop() if maps else [])
    values = {"cb_nav.x_m": 0.3, "cb_nav.y_m": 0.6, "cb_nav.yaw_deg": 90.0}
    exe = SimpleNamespace(
        ctx=SimpleNamespace(cfg=SimpleNamespace(map=SimpleNamespace(origin_x_m=0.0, origin_y_m=0.0, cell_m=0.03,
                                                                    nx=32, ny=32)),
                            clock=SimpleNamespace(now=lambda: 4.0)),
        bus=SimpleNamespace(subscribe=lambda *_a, **_k: sub),
        telemetry=SimpleNamespace(values=values, get=values.get),
        events=SimpleNamespace(listeners=[]))
    recorded, live = _Rec(), _Rec()
    tap = CliffbotTap(exe, rerun_cli.LiveSource(recorded, "cliffbot"),  # type: ignore[arg-type]
                      mirrors=(rerun_cli.LiveSource(live, "cliffbot"),))
    exe.events.listeners[0](Event(3.5, 7, "mission.DRIVE", Severity.ACTIVITY_HI, "to station 1"))
    tap.poll()
    paths = [p for p, _ in live.logged]
    assert paths == ["/cliffbot/map/elevation", "/cliffbot/map/rover", "/cliffbot/map/track", "/cliffbot/events"]
    assert paths == [p for p, _ in recorded.logged] and live.times == recorded.times == [4.0, 4.0, 3.5]
    rover = dict(live.logged)["/cliffbot/map/rover"]
    assert rover.origins.as_arrow_array().to_pylist()[0] == pytest.approx([10.0, 12.0])  # type: ignore[attr-defined]
    tap.poll()  # nothing new: nothing drawn but the pose, at most every 0.2 s (the clock stands)
    assert len(live.logged) == 4
    tap.close()
    assert exe.events.listeners == []
