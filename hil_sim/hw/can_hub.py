"""The bench's CAN hub: relays ``udp_hub`` frames among the bench's processes.

``safer-hil serve`` runs one (a thread) on ``127.0.0.1:PORT``; every process on the bench's CAN
bus opens python-can ``udp_hub`` with that address as channel (:mod:`fsw.drivers.can_udp`,
which also describes the datagrams). The hub relays each frame datagram, unchanged, to every
other node it knows, never back to its sender: every node sees every frame but its own, as on
a CAN bus. A node is known from its first datagram (a join, or any frame) until it leaves or is
silent for ``expire_s`` (nodes re-join every second). Datagrams of an unknown kind are dropped
and counted (``bad``). Bound to 127.0.0.1 unless the caller names another address: a bus that
spans machines is a choice (docs/hil.md, "A bench across machines"). A second hub on the same
port fails to bind (no address reuse), so two benches never share a bus by accident.
"""

from __future__ import annotations

import socket
import threading
import time

from fsw.drivers.can_udp import FRAME, JOIN, LEAVE, MAGIC, MAX_DATAGRAM, RCVBUF_BYTES

Addr = tuple[str, int]


class CanHub:
    """A UDP relay: every frame from one node to all others (see the module docstring)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, expire_s: float = 5.0, max_nodes: int = 64) -> None:
        self.expire_s, self.max_nodes = expire_s, max_nodes
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise OSError(exc.errno, f"CAN hub {host}:{port}: {exc.strerror or exc}") from None
        self.sock.settimeout(0.2)
        self.nodes: dict[Addr, float] = {}  # node -> last time heard (monotonic)
        self.frames = self.relayed = self.bad = self.refused_nodes = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def address(self) -> Addr:
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def channel(self) -> str:
        """The ``udp_hub`` channel string of this hub."""
        return "{}:{}".format(*self.address)

    def start(self) -> CanHub:
        self._thread = threading.Thread(target=self._run, name="can-hub", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.sock.close()

    def __enter__(self) -> CanHub:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- relay -------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(MAX_DATAGRAM)
            except TimeoutError:
                with self._lock:
                    self._expire(time.monotonic())
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue  # e.g. an ICMP error for a node gone: it expires
            self.handle(data, (str(addr[0]), int(addr[1])), time.monotonic())

    def handle(self, data: bytes, sender: Addr, now: float) -> None:
        """Act on one datagram from ``sender`` (public for tests that drive the hub by hand)."""
        kind, body = data[:1], data[1:]
        with self._lock:
            if kind == FRAME and body:
                self._heard(sender, now)
                for node in list(self.nodes):
                    if node != sender:
                        self._forward(data, node)
                self.frames += 1  # after the relay: a test that waits for this count finds them queued
            elif kind == JOIN and body == MAGIC:
                self._heard(sender, now)
            elif kind == LEAVE and body == MAGIC:
                self.nodes.pop(sender, None)
            else:
                self.bad += 1
            self._expire(now)

    def _heard(self, node: Addr, now: float) -> None:
        if node not in self.nodes and len(self.nodes) >= self.max_nodes:
            self.refused_nodes += 1
            return
        self.nodes[node] = now

    def _forward(self, data: bytes, node: Addr) -> None:
        try:
            self.sock.sendto(data, node)
            self.relayed += 1
        except OSError:
            self.nodes.pop(node, None)  # unreachable: it re-joins if it is still there

    def _expire(self, now: float) -> None:
        for node, t in list(self.nodes.items()):
            if now - t > self.expire_s:
                del self.nodes[node]
