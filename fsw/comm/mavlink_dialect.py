"""The one place that selects MAVLink 2 and the common dialect before pymavlink is imported.

pymavlink reads ``MAVLINK20`` and ``MAVLINK_DIALECT`` from the environment when ``mavutil``
is first imported and binds its ``mavlink`` module for the whole process, so every module of
``fsw`` and ``ground`` that touches MAVLink imports it from here (``from
fsw.comm.mavlink_dialect import mavlink``) and never imports pymavlink directly.

Also the MAVLink constants this project chose (documented in docs/ground.md): the rover's
ids, the command id that carries the executive's command dictionary, the epoch of the
signing timestamps.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "common"

import sys  # noqa: E402
from types import ModuleType  # noqa: E402

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402


def load_mavutil() -> ModuleType:
    """pymavlink's ``mavutil`` (connections, for the ground tools and tests), bound to MAVLink 2
    and the common dialect. The flight software does not import it: it needs only the dialect
    module (a sans-I/O codec), and mavutil costs 6 MB of memory (issue 15)."""
    from pymavlink import mavutil

    _check(mavutil)
    return mavutil


def _check(mavutil: ModuleType) -> None:
    # mavutil binds the dialect on first import; a process that imported it earlier with other
    # settings would hand us MAVLink 1 or another dialect. Refuse that loudly.
    if getattr(mavutil, "mavlink", None) is not None and mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        raise ImportError("pymavlink.mavutil was imported before fsw.comm.mavlink_dialect without MAVLINK20=1")


if "pymavlink.mavutil" in sys.modules:
    _check(sys.modules["pymavlink.mavutil"])

#: COMMAND_LONG.command that carries a dictionary command: param1 = opcode (docs/ground.md).
MAV_CMD_DICTIONARY = mavlink.MAV_CMD_USER_1
#: Signing timestamps count 10 us units since 2015-01-01T00:00:00Z (MAVLink 2 signing spec).
SIGNING_EPOCH_UNIX_S = 1420070400
SIGNATURE_LEN = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
#: Largest MAVLink 2 frame: 10 header + 255 payload + 2 CRC + 13 signature bytes.
MAX_FRAME_BYTES = 10 + 255 + 2 + SIGNATURE_LEN


def new_codec(system_id: int, component_id: int) -> mavlink.MAVLink:
    """A sans-I/O MAVLink 2 encoder/parser: ``pack`` to bytes, ``parse_buffer`` from bytes.

    Robust parsing turns bad prefixes, CRCs and lengths into ``BAD_DATA`` messages instead
    of exceptions. No key is installed: signatures are checked by ``mavlink_signing``.
    """
    mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
    mav.robust_parsing = True
    return mav


def signing_timestamp(unix_s: float) -> int:
    """The MAVLink signing timestamp (10 us units since 2015) for a Unix time."""
    return max(0, int((unix_s - SIGNING_EPOCH_UNIX_S) * 100_000))


__all__ = ["MAVLink", "MAV_CMD_DICTIONARY", "MAX_FRAME_BYTES", "SIGNATURE_LEN",
           "SIGNING_EPOCH_UNIX_S", "load_mavutil", "mavlink", "new_codec", "signing_timestamp"]
MAVLink = mavlink.MAVLink
