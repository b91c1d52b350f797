"""Flight driver of the stereo camera pair, with one backend per kind of source.

The backend is chosen by one string (``devices.camera_source``, python-can style):

* ``sim``: a source the HIL bench injects (resource ``camera_source``): either an object with
  ``request(seq)`` / ``receive() -> list[CameraReply]`` or a plain callable returning
  ``(left, right)`` or ``(left, right, t_capture_s)`` (lockstep, in process);
* ``tcp://HOST:PORT``: the bench's camera server (multi-process), :mod:`fsw.comm.camera_frames`;
* ``cv:LEFT,RIGHT``: two OpenCV ``VideoCapture`` devices (indices or URLs/files), real cameras.

The driver keeps one capture outstanding: ``trigger(now)`` asks for a pair, ``poll(now)``
collects it (``latest``/``take()``); no pair within ``timeout_s``, a dropout or a broken
link is a fault bit and an event, and the next good pair clears it.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import Any, ClassVar, Protocol

import numpy as np

from fsw.comm import camera_frames as cf
from fsw.comm.camera_frames import CameraReply
from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

F_TIMEOUT, F_DROPOUT, F_LINK, F_BAD_DATA = 0x01, 0x02, 0x04, 0x08


class FrameSource(Protocol):
    def request(self, seq: int) -> None: ...
    def receive(self) -> list[CameraReply]: ...
    def close(self) -> None: ...


class CallableSource:
    """In-process source: ``fn()`` renders a pair on request."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.fn = fn
        self._out: list[CameraReply] = []

    def request(self, seq: int) -> None:
        got = self.fn()
        if got is None:
            self._out.append(CameraReply(seq, cf.DROPOUT, float("nan"), None, None))
            return
        left, right = got[0], got[1]
        t = float(got[2]) if len(got) > 2 else float("nan")
        self._out.append(CameraReply(seq, cf.OK, t, np.asarray(left, np.uint8), np.asarray(right, np.uint8)))

    def receive(self) -> list[CameraReply]:
        out, self._out = self._out, []
        return out

    def close(self) -> None:
        pass


class SocketSource:
    """Client of the bench camera server; connects lazily and again after a broken link."""

    def __init__(self, host: str, port: int, connect_timeout_s: float = 0.2) -> None:
        self.addr = (host, port)
        self.connect_timeout_s = connect_timeout_s
        self.sock: socket.socket | None = None
        self.decoder = cf.ReplyDecoder()

    def _connect(self) -> socket.socket:
        if self.sock is None:
            s = socket.create_connection(self.addr, timeout=self.connect_timeout_s)
            s.setblocking(False)
            self.sock, self.decoder = s, cf.ReplyDecoder()
        return self.sock

    def request(self, seq: int) -> None:
        try:
            self._connect().sendall(cf.encode_request(seq))
        except OSError:
            self.close()
            raise

    def receive(self) -> list[CameraReply]:
        if self.sock is None:
            return []
        chunks = []
        while True:
            try:
                data = self.sock.recv(1 << 20)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.close()
                raise
            if not data:
                self.close()
                raise ConnectionError("camera server closed the connection")
            chunks.append(data)
        return self.decoder.feed(b"".join(chunks)) if chunks else []

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class OpenCvSource:
    """Two ``cv2.VideoCapture`` devices grabbed back to back, converted to grayscale."""

    def __init__(self, left: str, right: str) -> None:
        import cv2

        self._cv2 = cv2
        self.caps = [cv2.VideoCapture(int(s) if s.isdigit() else s) for s in (left, right)]
        self._out: list[CameraReply] = []

    def request(self, seq: int) -> None:
        cv2 = self._cv2
        ok = [c.grab() for c in self.caps]
        imgs: list[Any] = [c.retrieve()[1] if g else None for c, g in zip(self.caps, ok, strict=True)]
        if any(i is None for i in imgs):
            self._out.append(CameraReply(seq, cf.DROPOUT, float("nan"), None, None))
            return
        gray = [np.asarray(i if i.ndim == 2 else cv2.cvtColor(i, cv2.COLOR_BGR2GRAY), np.uint8) for i in imgs]
        self._out.append(CameraReply(seq, cf.OK, float("nan"), gray[0], gray[1]))

    def receive(self) -> list[CameraReply]:
        out, self._out = self._out, []
        return out

    def close(self) -> None:
        for c in self.caps:
            c.release()


def make_source(spec: str, provided: Any = None) -> FrameSource | None:
    """The backend for ``spec``; ``provided`` is the bench's source for ``sim``."""
    if spec == "none":
        return None
    if spec == "sim":
        if provided is None:
            return None
        return provided if hasattr(provided, "request") else CallableSource(provided)
    if spec.startswith("tcp://"):
        host, _, port = spec[len("tcp://") :].rpartition(":")
        return SocketSource(host or "127.0.0.1", int(port))
    if spec.startswith("cv:"):
        left, _, right = spec[3:].partition(",")
        return OpenCvSource(left, right or left)
    raise ValueError(f"unknown camera source {spec!r} (none, sim, tcp://HOST:PORT, cv:LEFT,RIGHT)")


class CameraDriver(DriverBase):
    """One outstanding capture at a time, with timeout, dropout and link supervision."""

    FAULTS: ClassVar[dict[str, int]] = {
        "timeout": F_TIMEOUT,
        "dropout": F_DROPOUT,
        "link": F_LINK,
        "bad_data": F_BAD_DATA,
    }
    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("CAMERA_TIMEOUT", Severity.WARNING_HI, "camera: no pair for capture {seq} after {timeout_s:.1f} s"),
        EventDef("CAMERA_DROPOUT", Severity.WARNING_LO, "camera: capture {seq} returned {status}", throttle=5),
        EventDef("CAMERA_LINK_ERROR", Severity.WARNING_HI, "camera link: {error}", throttle=3),
        EventDef("CAMERA_BAD_DATA", Severity.WARNING_LO, "camera: {n} malformed reply(ies) refused", throttle=5),
        EventDef("CAMERA_RECOVERED", Severity.ACTIVITY_HI, "camera: pair {seq} received"),
        EventDef("CAMERA_NO_SOURCE", Severity.WARNING_HI, "camera: no source configured"),
    )

    def __init__(self, source: FrameSource | None, timeout_s: float = 2.0, error_hold_s: float = 2.0) -> None:
        super().__init__(error_hold_s)
        self.source, self.timeout_s = source, timeout_s
        self._seq = 0
        self._pending: tuple[int, float] | None = None
        self.latest: CameraReply | None = None
        self._fresh = False
        self.frames = self.timeouts = self.dropouts = self.link_errors = 0
        self._bad_seen = 0

    @property
    def busy(self) -> bool:
        return self._pending is not None

    def trigger(self, now: float) -> int | None:
        """Ask for a pair; returns its sequence number, or None (busy or no source)."""
        if self._pending is not None:
            return None
        if self.source is None:
            self._event("CAMERA_NO_SOURCE")
            return None
        self._seq += 1
        self._pending = (self._seq, now)
        try:
            self.source.request(self._seq)
        except Exception as exc:  # noqa: BLE001 - any backend failure is a link fault
            self._link_error(now, exc)
        return self._seq

    def poll(self, now: float) -> None:
        self.last_poll_s = now
        self._expire_holds(now)
        if self.source is None:
            return
        try:
            replies = self.source.receive()
        except Exception as exc:  # noqa: BLE001 - a broken link is a fault, not a crash
            self._link_error(now, exc)
            replies = []
        bad = getattr(getattr(self.source, "decoder", None), "errors", 0)
        if bad > self._bad_seen:
            self._event("CAMERA_BAD_DATA", n=bad - self._bad_seen)
            self._bad_seen = bad
            self._hold(F_BAD_DATA, now)
        for r in replies:
            self._on_reply(r, now)
        p = self._pending
        if p is not None and now - p[1] >= self.timeout_s:
            self.timeouts += 1
            self._pending = None
            self._set(F_TIMEOUT)
            self._event("CAMERA_TIMEOUT", seq=p[0], timeout_s=self.timeout_s)

    def _on_reply(self, r: CameraReply, now: float) -> None:
        if self._pending is None or r.seq != self._pending[0]:
            return  # a late answer to a capture already given up
        self._pending = None
        if r.status != cf.OK:
            self.dropouts += 1
            self._hold(F_DROPOUT, now)
            self._event("CAMERA_DROPOUT", seq=r.seq, status=cf.STATUS_NAMES.get(r.status, r.status))
            return
        if self.faults & (F_TIMEOUT | F_DROPOUT | F_LINK):
            self._event("CAMERA_RECOVERED", seq=r.seq)
        self._set(F_TIMEOUT | F_DROPOUT | F_LINK, False)
        self.frames += 1
        self.latest, self._fresh = r, True

    def take(self) -> CameraReply | None:
        """The newest pair not taken before, or None."""
        if not self._fresh:
            return None
        self._fresh = False
        return self.latest

    def _link_error(self, now: float, exc: BaseException) -> None:
        self.link_errors += 1
        self._pending = None
        self._set(F_LINK)
        self._event("CAMERA_LINK_ERROR", error=f"{type(exc).__name__}: {exc}")

    def close(self) -> None:
        if self.source is not None:
            self.source.close()
