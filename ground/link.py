"""A ground station's end of the link: a pymavlink connection that keeps itself alive.

Announces itself with a GCS HEARTBEAT every second (so a rover on ``udpin`` learns where to
send, and its ``gcs_link`` channel goes up), and reopens the connection after an error
(serial unplugged, network down) with a back-off, counting reconnections.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

from fsw.comm.mavlink_dialect import load_mavutil, mavlink

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER


class LinkError(ValueError):
    """The URL cannot be opened."""


def open_connection(url: str, baud: int = 57600) -> Any:
    """A mavutil connection for ``udpin:``/``udpout:``/``serial:`` URLs (as the rover's)."""
    device = url
    if url.startswith("serial:"):
        device = url.removeprefix("serial:")
    elif not url.startswith(("udpin:", "udpout:", "tcp:", "tcpin:")):
        raise LinkError(f"{url}: expected udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE")
    try:
        return load_mavutil().mavlink_connection(device, baud=baud, source_system=GCS_SYSTEM_ID,
                                                 source_component=GCS_COMPONENT_ID, autoreconnect=True)
    except (OSError, ValueError) as exc:
        raise LinkError(f"{url}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - pyserial's SerialException and friends
        raise LinkError(f"{url}: {exc}") from None


class GroundLink:
    """Receive messages and keep announcing ourselves; reconnect on errors."""

    def __init__(self, url: str, baud: int = 57600, retry_s: float = 1.0) -> None:
        self.url, self.baud, self.retry_s = url, baud, retry_s
        self.conn: Any = open_connection(url, baud)
        self.reconnects = 0
        self.error: str | None = None
        self._next_hb = 0.0
        self._next_retry = 0.0

    def recv(self, timeout_s: float) -> Any:
        """One message (or None after ``timeout_s``); never raises on link trouble."""
        now = time.monotonic()
        if self.conn is None:
            if now < self._next_retry:
                time.sleep(min(timeout_s, self._next_retry - now))
                return None
            try:
                self.conn = open_connection(self.url, self.baud)
                self.reconnects += 1
                self.error = None
            except LinkError as exc:
                self.error, self._next_retry = str(exc), now + self.retry_s
                return None
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.send_heartbeat()
        try:
            return self.conn.recv_match(blocking=True, timeout=timeout_s)
        except Exception as exc:  # noqa: BLE001 - socket/serial errors: drop the connection, retry
            self._drop(f"receive: {exc}")
            return None

    def send_heartbeat(self) -> None:
        try:
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                         mavlink.MAV_STATE_ACTIVE)
        except Exception as exc:  # noqa: BLE001 - e.g. udpin before any peer, or a dead port
            if not isinstance(exc, (AttributeError, TypeError)) and "Destination" not in str(exc):
                self._drop(f"send: {exc}")

    def _drop(self, why: str) -> None:
        self.error = why
        with contextlib.suppress(Exception):  # closing a broken connection
            self.conn.close()
        self.conn = None
        self._next_retry = time.monotonic() + self.retry_s

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None
