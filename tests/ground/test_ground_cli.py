"""Issue 7, item 4: ``safer-ground`` listen / send / plot / map / keygen: help, exit codes,
bad input, and each subcommand against a lockstep rover on loopback."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import ground_demo
import pytest
from ground_demo import MemoryLink, RoverThread, free_udp_port, write_config

from fsw.settings import load_settings
from ground.cli import main


def _code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse usage errors
        return int(exc.code or 0)


def test_console_script_help() -> None:
    """Issue 7, item 4: the installed ``safer-ground`` explains itself."""
    exe = Path(sys.executable).parent / "safer-ground"
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and all(w in out.stdout for w in ("listen", "send", "plot", "map", "keygen"))


def test_usage_errors_and_bad_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Exit code 2 on usage errors, bad files and bad configuration; one clear line, no traceback."""
    garbage = tmp_path / "garbage.tlog"
    garbage.write_bytes(bytes(range(256)) * 4)
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    badkey = tmp_path / "bad.key"
    badkey.write_text("not a key")
    goodkey = tmp_path / "good.key"
    assert _code(["keygen", str(goodkey)]) == 0 and oct(goodkey.stat().st_mode & 0o777) == "0o600"
    cases = [
        [], ["send", "exec.NOOP"], ["plot", str(garbage)], ["frobnicate"],
        ["plot", str(tmp_path / "missing.tlog"), "--out", str(tmp_path / "p")],
        ["plot", str(garbage), "--out", str(tmp_path / "p")],
        ["plot", str(empty), "--out", str(tmp_path / "p")],
        ["map", str(garbage), "--out", str(tmp_path / "m.png")],
        ["map", str(tmp_path), "--out", str(tmp_path / "m.png")],
        ["send", "exec.NOOP", "--key", str(badkey)],
        ["send", "exec.NOOP", "--key", str(tmp_path / "nokey")],
        ["send", "exec.NO_SUCH", "--key", str(goodkey)],
        ["send", "exec.SET_TASK_ENABLED", "health", "maybe", "--key", str(goodkey)],
        ["send", "mavlink.SET_BUDGET", "--key", str(goodkey)],
        ["keygen", str(goodkey)],
        ["--config", str(tmp_path / "none.toml"), "listen", "udpin:127.0.0.1:1"],
        ["--config", str(badkey), "listen", "udpin:127.0.0.1:1"],
        ["listen", "bogus:url"],
    ]
    for argv in cases:
        assert _code(argv) == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err and "not a .tlog" in err and "expected 64 hex digits" in err


@pytest.mark.slow
def test_plot_and_map_from_a_run(tmp_path: Path, key_file: Path, demo_kind: None,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 7, item 4: plot writes task timing, slips, mapped cells, link and channel PNGs;
    map writes the reassembled preview."""
    tlog = tmp_path / "run.tlog"
    cfg_file = write_config(tmp_path / "rover.toml", {"url": "udpout:127.0.0.1:9", "key_file": str(key_file),
                                                      "tlog_path": str(tlog), "image_period_s": 2.0})
    exe = ground_demo.build(load_settings(cfg_file))
    exe.run_lockstep(150)
    exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    out = tmp_path / "plots"
    assert main(["--config", str(cfg_file), "plot", str(tlog), "--out", str(out)]) == 0
    for name in ("task_timing.png", "slips.png", "mapped_cells.png", "link.png", "channels.png"):
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape[0] > 200, name
    png = tmp_path / "map.png"
    assert main(["--config", str(cfg_file), "map", str(tlog), "--out", str(png), "--scale", "2"]) == 0
    assert cv2.imread(str(png)).shape == (192, 256, 3)
    assert main(["--config", str(cfg_file), "map", str(tlog), "--out", str(png), "--index", "99"]) == 2
    text = capsys.readouterr().out
    assert "task_timing.png" in text and "complete" in text


def test_keygen_from_passphrase(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The key MAVProxy derives from ``signing key PASSPHRASE`` (SHA-256), for shared use."""
    import hashlib
    import io

    from fsw.comm.mavlink_signing import load_key

    monkeypatch.setattr(sys, "stdin", io.StringIO("correcthorsebattery\n"))
    assert main(["keygen", str(tmp_path / "p.key"), "--passphrase-stdin"]) == 0
    assert load_key(tmp_path / "p.key")[0] == hashlib.sha256(b"correcthorsebattery").digest()
    for bad in ("short\n", "two words here\n"):
        monkeypatch.setattr(sys, "stdin", io.StringIO(bad))
        assert main(["keygen", str(tmp_path / "q.key"), "--passphrase-stdin"]) == 2


def _budget(exe: Any) -> int:
    return int(exe.tasks["mavlink"].adapter.budget_bytes)


def test_send_signed_command(tmp_path: Path, key_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 7, item 4: ``send`` signs, waits for COMMAND_ACK; exit 0 accepted, 1 refused,
    3 when nobody answers."""
    port = free_udp_port()
    cfg_file = write_config(tmp_path / "rover.toml", {"url": f"udpin:127.0.0.1:{port}", "key_file": str(key_file)},
                            demo=False)
    exe = ground_demo.build(load_settings(cfg_file))
    other = tmp_path / "other.key"
    main(["keygen", str(other)])
    base = ["--config", str(cfg_file), "send"]
    with RoverThread(exe):
        assert main(base + ["mavlink.SET_BUDGET", "budget_bytes=400", "--key", str(key_file)]) == 0
        assert _budget(exe) == 400
        assert main(base + ["mavlink.set_budget", "500", "--key", str(other), "--link-id", "3"]) == 1
        assert main(base + ["exec.SET_TASK_ENABLED", "nope", "true", "--key", str(key_file)]) == 1
    assert _budget(exe) == 400
    out = capsys.readouterr().out
    assert "ACCEPTED" in out and "DENIED (bad signature)" in out and "FAILED" in out
    assert main(base + ["exec.NOOP", "--key", str(key_file), "--timeout", "0.3"]) == 3


class SteppedGround:
    """Ground time and the ground link of ``listen``, stepped: no sockets, threads or sleeps.

    ``lives`` are the ground-time intervals in which a rover runs (a fresh lockstep executive
    each: a restart). Each ``recv`` hands over the next message the rover sent or, with none
    queued, runs the live rover one frame (0.01 s of ground time: 10x real time, as
    ``RoverThread``) or, with no rover, lets the receive timeout pass. ``monotonic`` is the
    clock ``listen`` reads, so its screens depend on the script only."""

    def __init__(self, cfg: Any, lives: list[tuple[float, float]], monkeypatch: pytest.MonkeyPatch) -> None:
        from fsw.comm.mavlink_dialect import new_codec

        self.cfg, self.lives, self.t = cfg, lives, 0.0
        self.codec = new_codec(255, 190)
        self.queue: list[Any] = []
        self.rovers: dict[int, tuple[Any, MemoryLink]] = {}
        self.reconnects, self.error = 0, None
        self.links: list[MemoryLink] = []
        monkeypatch.setattr("fsw.tasks.mavlink_task.open_transport", self._open_transport)

    def _open_transport(self, url: str, baud: int) -> MemoryLink:
        self.links.append(MemoryLink())
        return self.links[-1]

    def __call__(self, url: str, baud: int) -> SteppedGround:  # stands in for GroundLink(url, baud)
        return self

    def monotonic(self) -> float:
        return self.t

    def recv(self, timeout_s: float) -> Any:
        if not self.queue:
            life = next((i for i, (a, b) in enumerate(self.lives) if a <= self.t < b), None)
            if life is None:
                self.t += timeout_s
                return None
            if life not in self.rovers:
                exe = ground_demo.build(self.cfg)
                self.rovers[life] = (exe, self.links[-1])
            exe, link = self.rovers[life]
            exe.run_lockstep(1)
            self.t += 0.01
            for frame in link.sent[-1]:
                self.queue.extend(m for m in self.codec.parse_buffer(frame) or [] if m.get_type() != "BAD_DATA")
        return self.queue.pop(0) if self.queue else None

    def close(self) -> None:
        for exe, _ in self.rovers.values():
            exe.tasks["mavlink"].close()


def test_listen_live_view_and_relink(tmp_path: Path, key_file: Path, demo_kind: None,
                                     monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 7, item 4: the live view shows mode, pose, task timing, channels and events,
    marks the link lost while the rover is silent, and picks it up again after a restart.
    Stepped: a rover for 1 s, silence for 1 s, a restarted rover for 1 s, a screen every 0.1 s."""
    import types

    cfg_file = write_config(tmp_path / "rover.toml", {"url": "udpout:127.0.0.1:9", "key_file": str(key_file)})
    ground = SteppedGround(load_settings(cfg_file), [(0.0, 1.0), (2.0, 3.0)], monkeypatch)
    monkeypatch.setattr("ground.link.GroundLink", ground)
    monkeypatch.setattr("ground.listen.time", types.SimpleNamespace(monotonic=ground.monotonic))
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)  # one screen per refresh
    rc = main(["--config", str(cfg_file), "listen", "udpin:127.0.0.1:9", "--duration", "3.0",
               "--timeout", "0.6", "--refresh", "0.1", "--no-color"])
    assert rc == 0 and len(ground.rovers) == 2
    screens = [sc for sc in capsys.readouterr().out.split("\x1b[H\x1b[2J") if sc.strip()]
    state = ["UP" if "LINK UP" in sc else "LOST" if "LINK LOST" in sc else "WAIT" for sc in screens]
    # Up from the first screen while the first rover runs; lost once its last heartbeat is
    # older than 0.6 s (the silence from t = 1 s); up again with the restarted rover (t = 2 s).
    assert re.fullmatch(r"U{12,}L{3,}U{5,}", "".join(x[0] for x in state)), state
    last = screens[-1]
    assert "dictionary" in last and ": ok" in last
    assert "Mode " in last and "Pose x" in last and "Mast pan" in last
    assert "mavlink.tx_bytes" in last and "demo.temperature_c" in last
    assert "demo.STATE: mission state" in last
    assert "health" in last.split("task")[1]  # task timing table


def test_render_link_lost_and_colours(key_file: Path) -> None:
    """The view marks a lost link and colours out-of-limit channels red."""
    from fsw.comm.mavlink_dialect import mavlink, new_codec
    from ground.dictionary import load_dictionary
    from ground.listen import RED, Painter, render
    from ground.state import GroundState

    d = load_dictionary()
    st = GroundState(d)
    codec = new_codec(1, 1)
    for msg in (mavlink.MAVLink_heartbeat_message(10, 0, 1, 0, 3, 3),
                mavlink.MAVLink_named_value_int_message(0, b"dict_crc", d.crc),
                mavlink.MAVLink_named_value_int_message(0, b"3:overruns", 2)):
        st.feed(new_codec(2, 2).parse_buffer(msg.pack(codec))[0], 10.0)
    screen = render(st, d, "udpin:x", 20.0, Painter(True))
    assert "LINK LOST" in screen and RED in screen and "exec.overruns" in screen


def test_map_renders_a_checkpoint_in_metres(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 29, item 1: ``safer-ground map CHECKPOINT`` draws the saved map (+y up, axes in metres);
    a damaged checkpoint is one line and exit 2."""
    import numpy as np

    from fsw.core.geometry import MapGrid
    from fsw.core.map import checkpoint
    from fsw.core.map.elevation_map import ElevationMap

    emap = ElevationMap(MapGrid(0.0, 0.0, 0.05, 60, 40))
    z = np.full((40, 60), np.nan)
    z[:20, :] = 0.3  # the lower half (low y) mapped
    emap.z, emap.n = z, np.isfinite(z).astype(np.int32)
    ck = tmp_path / "map_000002.ckpt"
    ck.write_bytes(checkpoint.encode(emap, 2, 60.0))
    png = tmp_path / "ck.png"
    assert main(["map", str(ck), "--out", str(png)]) == 0
    assert "1200 mapped" in capsys.readouterr().out
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 200 and img.shape[1] > 200
    h, w = img.shape[:2]  # +y up: the mapped low-y half is drawn below the unknown (white) half
    assert (img[int(0.3 * h), int(0.4 * w)] > 240).all() and not (img[int(0.7 * h), int(0.4 * w)] > 240).all()
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(ck.read_bytes()[:-3])
    assert main(["map", str(bad), "--out", str(png)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unreadable" in err[0]


def test_listen_keeps_its_header_filters_channels_and_shows_the_step() -> None:
    """Issue 29, item 5: with 150 channels the screen fits a 40-row terminal with the header on
    top; --channels filters by pattern; the mission's step shows as 'step k of N'."""
    from ground.dictionary import load_dictionary
    from ground.listen import Painter, render
    from ground.state import GroundState

    d = load_dictionary()
    st = GroundState(d)
    st.channels.update({f"task{i:03d}.value": (float(i), 10.0) for i in range(150)})
    st.channels["mission.step"] = (3.0, 10.0)
    screen = render(st, d, "udpin:x", 11.0, Painter(False), rows=40, steps=20).splitlines()
    assert len(screen) <= 40 and screen[0].startswith("safer-ground udpin:x")
    assert "step 3 of 20" in screen[2] and any("more channels" in ln for ln in screen)
    full = render(st, d, "udpin:x", 11.0, Painter(False)).splitlines()
    assert len(full) > 70  # without a height every channel is listed
    only = render(st, d, "udpin:x", 11.0, Painter(False), channels=("mission.*", "task00?.*"))
    assert "mission.step" in only and "task009.value" in only and "task010.value" not in only


@pytest.mark.parametrize("config", ["fsw.toml", "cliffbot.toml"])
def test_the_links_mode_and_pose_channels_are_channels_the_agent_publishes_once(config: str) -> None:
    """What the MAVLink task sends as the HEARTBEAT's mode and the vehicle's pose are channels of
    that agent's dictionary; the Cliff-bot's estimate is its navigation's (``cb_nav``), published
    by no other task."""
    from ground.dictionary import load_dictionary

    d = load_dictionary(Path(__file__).resolve().parents[2] / "config" / config)
    names = {info.name for info in d.channels.values()}
    mav = d.cfg.mavlink
    for name in (mav.mission_state_channel, *mav.pose_channels, *mav.mast_channels):
        assert name == "" or name in names, name
    if config == "cliffbot.toml":
        assert mav.pose_channels == ("cb_nav.x_m", "cb_nav.y_m", "", "", "", "cb_nav.yaw_deg")
        for ch in ("x_m", "y_m", "yaw_deg", "sigma_m"):
            assert [n for n in names if n.endswith(f".{ch}")] == [f"cb_nav.{ch}"]
