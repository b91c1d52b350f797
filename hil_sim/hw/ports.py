"""Device ends of the serial line for multi-process mode: a pty or a TCP socket.

The flight side opens the other end with pyserial like a real port: the pty's slave path
(``/dev/pts/N``) or ``socket://HOST:PORT``. Both device ends are non-blocking and never
raise on a host that is absent or gone: bytes written with nobody listening are dropped
(counted), as on a UART with no cable.
"""

from __future__ import annotations

import contextlib
import os
import socket
import tty
from pathlib import Path


class PtyDevicePort:
    """The device (master) end of a pty; ``path`` is the slave the flight software opens."""

    def __init__(self, link: str | Path | None = None) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: a byte pipe like a UART
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self._slave)
        self.link = Path(link) if link else None
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
            self.link.symlink_to(self.path)
        self.dropped_bytes = 0

    def read(self, size: int = 1) -> bytes:
        try:
            return os.read(self.master, size)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO while no slave is open
            return b""

    def write(self, data: bytes) -> int:
        try:
            n = os.write(self.master, data)
        except (BlockingIOError, InterruptedError, OSError):
            n = 0
        self.dropped_bytes += len(data) - n
        return n

    def close(self) -> None:
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link is not None:
            with contextlib.suppress(OSError):
                self.link.unlink()


class TcpDevicePort:
    """A TCP listener taking one flight connection at a time (``socket://HOST:PORT``)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self.listener = socket.create_server((host, port))
        self.listener.setblocking(False)
        self.address = self.listener.getsockname()[:2]
        self.conn: socket.socket | None = None
        self.dropped_bytes = 0
        self.connections = 0

    @property
    def url(self) -> str:
        return f"socket://{self.address[0]}:{self.address[1]}"

    def _accept(self) -> socket.socket | None:
        if self.conn is None:
            try:
                conn, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return None
            conn.setblocking(False)
            self.conn = conn
            self.connections += 1
        return self.conn

    def _drop_conn(self) -> None:
        if self.conn is not None:
            with contextlib.suppress(OSError):
                self.conn.close()
            self.conn = None

    def read(self, size: int = 1) -> bytes:
        conn = self._accept()
        if conn is None:
            return b""
        try:
            data = conn.recv(size)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            self._drop_conn()
            return b""
        if not data:  # the flight side closed: wait for the next connection
            self._drop_conn()
        return data

    def write(self, data: bytes) -> int:
        conn = self._accept()
        if conn is None:
            self.dropped_bytes += len(data)
            return 0
        try:
            n = conn.send(data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError:
            self._drop_conn()
            n = 0
        self.dropped_bytes += len(data) - n
        return n

    def close(self) -> None:
        self._drop_conn()
        with contextlib.suppress(OSError):
            self.listener.close()
