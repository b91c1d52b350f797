"""``safer-ground send CMD [ARGS] --key FILE``: one signed command, waiting for its COMMAND_ACK.

The command is named as in the dictionary (``exec.NOOP``, ``mavlink.SET_BUDGET``; case does
not matter) or by opcode; arguments are ``name=value`` or positional in declared order.
It travels as COMMAND_LONG ``MAV_CMD_USER_1`` with ``param1`` = opcode (docs/ground.md),
signed with the key. Exit code: 0 ACCEPTED, 1 DENIED / FAILED / UNSUPPORTED, 2 usage error
or bad file, 3 no heartbeat or no COMMAND_ACK in time.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from fsw.comm.mavlink_commands import Reason, encode_args, parse_cli_value, result_name
from fsw.comm.mavlink_dialect import MAV_CMD_DICTIONARY, mavlink
from fsw.comm.mavlink_signing import load_key
from ground.dictionary import GroundDictionary
from ground.link import GCS_SYSTEM_ID

HELP = "send one signed command and wait for its COMMAND_ACK (exit code reflects it)"
EXIT_ACCEPTED, EXIT_REFUSED, EXIT_USAGE, EXIT_TIMEOUT = 0, 1, 2, 3


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("command", metavar="CMD", help="dictionary command (task.NAME) or opcode")
    p.add_argument("args", nargs="*", metavar="ARG", help="arguments: name=value or positional values")
    p.add_argument("--key", required=True, metavar="FILE", help="signing key file (64 hex digits)")
    p.add_argument("--url", default=None,
                   help="link (default: the rover's url from the config turned around: rover "
                        "udpout:H:P -> udpin:H:P, rover udpin:H:P -> udpout:H:P)")
    p.add_argument("--baud", type=int, default=57600, help="serial line rate")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S",
                   help="wait this long for the heartbeat and for the ACK")
    p.add_argument("--retries", type=int, default=0,
                   help="resend after a timeout (new signature; may run the command twice if only the ACK was lost)")
    p.add_argument("--link-id", type=int, default=1, help="signing link id of this ground station")


def parse_args_for(cdef: Any, values: list[str]) -> dict[str, Any]:
    """``name=value`` or positional words -> typed arguments; raises ValueError."""
    declared = {a.name: a for a in cdef.args}
    out: dict[str, Any] = {}
    positional = [v for v in values if "=" not in v]
    if positional and len(positional) != len(values):
        raise ValueError("mix of positional and name=value arguments")
    pairs = zip(declared, positional, strict=False) if positional else (v.split("=", 1) for v in values)
    for name, text in pairs:
        if name not in declared:
            raise ValueError(f"unknown argument {name!r} (declared: {', '.join(declared) or 'none'})")
        out[name] = parse_cli_value(declared[name], text)
    if len(positional) > len(declared):
        raise ValueError(f"{len(positional)} values for {len(declared)} arguments")
    missing = [n for n in declared if n not in out]
    if missing:
        raise ValueError(f"missing argument {missing[0]!r}")
    return out


def ground_url(rover_url: str) -> str:
    kind, _, rest = rover_url.partition(":")
    return {"udpout": f"udpin:{rest}", "udpin": f"udpout:{rest}"}.get(kind, rover_url)


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from ground.link import GroundLink, LinkError

    try:
        name, opcode, cdef = d.command(args.command)
        params = encode_args(cdef, parse_args_for(cdef, args.args))
        key, _ = load_key(args.key)
    except (KeyError, ValueError) as exc:  # KeyFileError is a ValueError
        msg = exc.args[0] if isinstance(exc, KeyError) else str(exc)
        print(f"safer-ground send: {msg}", file=sys.stderr)
        return EXIT_USAGE
    if args.timeout <= 0 or args.retries < 0 or not 0 <= args.link_id <= 255:
        print("safer-ground send: --timeout must be positive, --retries >= 0, --link-id 0..255", file=sys.stderr)
        return EXIT_USAGE
    url = args.url or ground_url(d.cfg.mavlink.url)
    try:
        link = GroundLink(url, args.baud)
    except LinkError as exc:
        print(f"safer-ground send: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        return _exchange(link, key, args, name, opcode, params)
    finally:
        link.close()


def _exchange(link: Any, key: bytes, args: argparse.Namespace, name: str, opcode: int, params: list[float]) -> int:
    conn = link.conn
    # see the rover whatever key signs its downlink; the ACK's own authenticity is reported
    conn.setup_signing(key, sign_outgoing=True, link_id=args.link_id, allow_unsigned_callback=lambda mav, msg_id: True)
    deadline = time.monotonic() + args.timeout
    hb = None
    while hb is None and time.monotonic() < deadline:
        msg = link.recv(0.1)
        if msg is not None and msg.get_type() == "HEARTBEAT" and msg.type != mavlink.MAV_TYPE_GCS:
            hb = msg
    if hb is None:
        print(f"safer-ground send: no rover heartbeat on {link.url} within {args.timeout:g} s", file=sys.stderr)
        return EXIT_TIMEOUT
    target = hb.get_srcSystem(), hb.get_srcComponent()
    for attempt in range(args.retries + 1):
        conn.mav.command_long_send(target[0], target[1], MAV_CMD_DICTIONARY, attempt, float(opcode), *params)
        ack = _wait_ack(link, opcode, time.monotonic() + args.timeout)
        if ack is not None:
            result = result_name(ack.result)
            reason = Reason(ack.progress).name if ack.progress in Reason._value2member_map_ else str(ack.progress)
            detail = f" ({reason.lower().replace('_', ' ')})" if ack.result != mavlink.MAV_RESULT_ACCEPTED \
                and ack.progress else ""
            auth = "" if getattr(ack, "_signed", False) else "  [ACK not signed with this key]"
            print(f"{name} (opcode 0x{opcode:x}) -> {result}{detail}{auth}")
            return EXIT_ACCEPTED if ack.result == mavlink.MAV_RESULT_ACCEPTED else EXIT_REFUSED
    print(f"safer-ground send: no COMMAND_ACK for {name} within {args.timeout:g} s "
          f"({args.retries + 1} attempt(s))", file=sys.stderr)
    return EXIT_TIMEOUT


def _wait_ack(link: Any, opcode: int, deadline: float) -> Any:
    while time.monotonic() < deadline:
        msg = link.recv(0.1)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "COMMAND_ACK" and msg.command == MAV_CMD_DICTIONARY and msg.result_param2 == opcode \
                and msg.target_system in (0, GCS_SYSTEM_ID):
            return msg
        if kind == "STATUSTEXT" and msg.severity <= mavlink.MAV_SEVERITY_NOTICE:
            text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else msg.text
            print(f"  rover: {text}")
    return None

