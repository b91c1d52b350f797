"""The camera end of the bench: rendered stereo pairs for the flight camera driver.

Two transports for one job (render the pair the true cameras see, on request):

* :class:`SimCameraLink` for lockstep, in process: the flight driver's ``sim`` backend calls
  ``request(seq)``; the bench renders in its next ``serve(now)`` (between executive frames)
  and the driver's ``receive()`` picks the pair up, one frame after the trigger, like a real
  exposure and transfer. Deterministic.
* :class:`CameraServer` for multi-process mode: a TCP server (loopback by default) speaking
  :mod:`fsw.comm.camera_frames`, one client at a time, rendering on a background thread.

Both consult the fault injector: ``camera_dropout`` leaves requests unanswered (or answers
DROPOUT). A renderer that fails answers UNAVAILABLE instead of breaking the link.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable

import numpy as np

from fsw.comm import camera_frames as cf
from fsw.comm.camera_frames import CameraReply
from hil_sim.faults import FaultInjector

SEND_TIMEOUT_S = 10.0  # longest wait for the client to take one reply
RenderFn = Callable[[], tuple[np.ndarray, np.ndarray, float]]


def _render_reply(seq: int, render: RenderFn, faults: FaultInjector) -> CameraReply | None:
    mode = faults.camera_dropout()
    if mode == "silent":
        return None
    if mode == "status":
        return CameraReply(seq, cf.DROPOUT, faults.now, None, None)
    try:
        left, right, t = render()
    except Exception:  # noqa: BLE001 - a renderer problem is an unavailable camera, not a bench crash
        return CameraReply(seq, cf.UNAVAILABLE, faults.now, None, None)
    return CameraReply(seq, cf.OK, t, left, right)


class SimCameraLink:
    """In-process camera for lockstep: requests now, pairs after the bench's next ``serve``."""

    def __init__(self, render: RenderFn, faults: FaultInjector | None = None) -> None:
        self.render, self.faults = render, faults or FaultInjector()
        self._requests: list[int] = []
        self._ready: list[CameraReply] = []
        self.rendered = 0

    # flight side (the driver's FrameSource protocol)
    def request(self, seq: int) -> None:
        self._requests.append(seq)

    def receive(self) -> list[CameraReply]:
        out, self._ready = self._ready, []
        return out

    def close(self) -> None:
        self._requests.clear()

    # bench side
    def serve(self, now: float) -> None:
        reqs, self._requests = self._requests, []
        for seq in reqs:
            reply = _render_reply(seq, self.render, self.faults)
            if reply is not None:
                self.rendered += reply.status == cf.OK
                self._ready.append(reply)


class CameraServer:
    """TCP camera server for multi-process mode (``tcp://HOST:PORT`` on the flight side)."""

    def __init__(
        self, render: RenderFn, faults: FaultInjector | None = None, host: str = "127.0.0.1", port: int = 0
    ) -> None:
        self.render, self.faults = render, faults or FaultInjector()
        self.listener = socket.create_server((host, port))
        self.listener.settimeout(0.2)
        self.address = self.listener.getsockname()[:2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera-server", daemon=True)
        self.served = self.bad_requests = self.clients = 0

    def start(self) -> CameraServer:
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except (TimeoutError, OSError):
                continue
            self.clients += 1
            with conn:
                self._serve_client(conn)

    def _serve_client(self, conn: socket.socket) -> None:
        conn.settimeout(0.2)
        dec = cf.RequestDecoder()
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            for seq in dec.feed(data):
                reply = _render_reply(seq, self.render, self.faults)  # render() snapshots the truth
                if reply is None:
                    continue
                try:
                    # A pair is ~0.6 MB: the client drains it once per frame, so on a loaded
                    # machine the send outlasts the 0.2 s receive timeout; a timed-out send used to
                    # drop the connection mid-reply (the flight saw a camera timeout, then a broken
                    # link). The send gets its own, longer timeout.
                    conn.settimeout(SEND_TIMEOUT_S)
                    conn.sendall(cf.encode_reply(reply.seq, reply.status, reply.t_capture_s, reply.left, reply.right))
                    conn.settimeout(0.2)
                    self.served += 1
                except OSError:
                    return
            self.bad_requests = dec.garbage_bytes

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self.listener.close()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
