"""Fixtures of the ground-link tests: a signing key, the demo task kind, an in-memory link."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import ground_demo  # noqa: E402

from fsw.comm.mavlink_signing import write_key  # noqa: E402
from fsw.tasks.registry import KINDS  # noqa: E402


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    """A fresh signing key in a temporary file (never a key from the repository)."""
    path = tmp_path / "rover.key"
    write_key(path)
    return path


@pytest.fixture
def demo_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(KINDS, *ground_demo.DEMO_KIND)


class MemoryLink:
    """A transport in memory: the task reads ``inbox`` (datagrams, or one byte stream when
    ``packetized`` is False); the frames it sends are kept per activation in ``sent``."""

    def __init__(self, packetized: bool = True) -> None:
        self.packetized = packetized
        self.inbox: list[bytes] = []
        self.sent: list[list[bytes]] = []
        self.fault: str | None = None
        self.tx_frames = self.tx_errors = self.rx_bytes = 0

    def recv(self, max_bytes: int) -> list[bytes]:
        self.sent.append([])  # recv starts each activation
        chunks, self.inbox = self.inbox, []
        if not self.packetized and chunks:
            chunks = [b"".join(chunks)]
        return chunks

    def send(self, frame: bytes) -> bool:
        self.sent[-1].append(frame)
        self.tx_frames += 1
        return True

    def close(self) -> None:
        pass


@pytest.fixture
def memory_link() -> MemoryLink:
    return MemoryLink()


def write_config(path: Path, mavlink: dict[str, object], demo: bool = True) -> Path:
    """A flight configuration file (TOML) for the ground tools' ``--config``."""
    tasks = [("demo", "ground_demo", "fast", 5.0)] if demo else [("busy", "busy", "fast", 5.0)]
    tasks += [("mavlink", "mavlink", "fast", 10.0), ("health", "health", "slow", 5.0)]
    lines = ["[executive]", "frame_period_s = 0.1",
             "[[executive.groups]]", 'name = "fast"', "divisor = 1",
             "[[executive.groups]]", 'name = "slow"', "divisor = 10", "offset = 3"]
    for name, kind, group, budget in tasks:
        lines += ["[[executive.tasks]]", f'name = "{name}"', f'kind = "{kind}"', f'group = "{group}"',
                  f"budget_ms = {budget}"]
    lines.append("[mavlink]")
    if demo:
        mavlink = {"mission_state_channel": "demo.state", "pose_channels": ["demo.x_m", "demo.y_m", "", "", "",
                                                                            "demo.yaw_deg"],
                   "mast_channels": ["demo.pan_deg", "demo.tilt_deg"], **mavlink}
    for k, v in mavlink.items():
        lines.append(f"{k} = {v!r}".replace("'", '"') if not isinstance(v, bool) else f"{k} = {str(v).lower()}")
    path.write_text("\n".join(lines) + "\n")
    return path


def free_udp_port() -> int:
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


class RoverThread:
    """Runs a lockstep executive paced at ~10x real time in a background thread."""

    def __init__(self, exe: object, step_s: float = 0.01) -> None:
        import threading

        self.exe, self.step_s = exe, step_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        import time

        while not self._stop.is_set():
            self.exe.run_lockstep(1)  # type: ignore[attr-defined]
            time.sleep(self.step_s)

    def __enter__(self) -> RoverThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
