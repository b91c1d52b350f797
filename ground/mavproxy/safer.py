"""The MAVProxy module ``safer``: SAFER's mode names, status and mode requests in MAVProxy.

Load it in MAVProxy with the repository on ``PYTHONPATH`` (MAVProxy lives in its own venv:
docs/ground.md, "MAVProxy")::

    PYTHONPATH=/path/to/mit-safer mavproxy.py --master=udpin:127.0.0.1:14550
    MAV> module load ground.mavproxy.safer

MAVProxy names a vehicle's mode with pymavlink's ``mavutil.mode_string_v10``, which knows
ArduPilot's and PX4's tables only. While loaded, this module answers that function for SAFER's
HEARTBEATs (:class:`~ground.mavproxy.modes.FleetModes`) and leaves every other vehicle to it,
so the prompt, MAVProxy's ``Mode ...`` announcements and its console show ``MOVE``, ``SAFE``,
``WAIT_MAP``, ... (unloading restores it). Commands:

* ``safer status``: each SAFER vehicle (system 1 RECON-bot, 2 Cliff-bot): mode, status, armed,
  last heard, last event;
* ``safer dictionary SYSID FILE.json``: that vehicle's dictionary (``safer-fsw --config FILE
  dictionary``), for the opcodes of its mode requests;
* ``safer mode NAME [SYSID]``: ask for a mode (``SAFE``, ``START``, ``RESUME``, ``RECOVER``)
  through the project's signed command path: a dictionary command in COMMAND_LONG, signed by
  MAVProxy's link once ``signing key PASSPHRASE`` is set (the rover refuses it unsigned); the
  COMMAND_ACK is printed when it arrives. MAVProxy's own ``mode`` command sends ArduPilot's
  SET_MODE, which the rover does not take: a SAFER mode is a mission state that only the
  mission's commands change.
"""

from __future__ import annotations

import time
from typing import Any

from fsw.comm.mavlink_dialect import load_mavutil
from ground.mavproxy.modes import REQUESTS, FleetModes, RequestError

try:
    from MAVProxy.modules.lib import mp_module
except ImportError:  # the project's venv: the logic (ground.mavproxy.modes) is tested without MAVProxy
    mp_module = None

USAGE = "usage: safer status | safer dictionary SYSID FILE.json | safer mode NAME [SYSID]"


def install(modes: FleetModes) -> Any:
    """Name SAFER's modes in pymavlink (``mavutil.mode_string_v10``); returns the original."""
    mavutil = load_mavutil()
    original = mavutil.mode_string_v10

    def mode_string_v10(msg: Any) -> str:
        name = modes.mode_string(msg)
        return name if name is not None else original(msg)

    mavutil.mode_string_v10 = mode_string_v10
    return original


def uninstall(original: Any) -> None:
    load_mavutil().mode_string_v10 = original


if mp_module is not None:

    class SaferModule(mp_module.MPModule):  # type: ignore[misc, valid-type]
        def __init__(self, mpstate: Any) -> None:
            super().__init__(mpstate, "safer", "SAFER mode names and mode requests", multi_vehicle=True)
            self.modes = FleetModes()
            self._original = install(self.modes)
            self.add_command("safer", self.cmd_safer, "SAFER vehicles: status, dictionary, mode",
                             ["status", "dictionary", "mode <" + "|".join(REQUESTS) + ">"])

        def unload(self) -> None:
            uninstall(self._original)

        def mavlink_packet(self, m: Any) -> None:
            for line in self.modes.feed(m, time.time()):
                print(line)

        def cmd_safer(self, args: list[str]) -> None:
            try:
                self._command(args)
            except RequestError as exc:
                print(f"safer: {exc}")

        def _command(self, args: list[str]) -> None:
            if args[:1] == ["status"]:
                for line in self.modes.status_lines(time.time()):
                    print(line)
            elif args[:1] == ["dictionary"] and len(args) == 3 and args[1].isdigit():
                n = self.modes.load_dictionary(int(args[1]), args[2])
                print(f"safer: system {args[1]}: {n} commands from {args[2]}")
            elif args[:1] == ["mode"] and len(args) in (2, 3) and (len(args) == 2 or args[2].isdigit()):
                system = int(args[2]) if len(args) == 3 else int(self.target_system)
                name, op, msg = self.modes.request(args[1], system)
                link = self.mpstate.master(system) or self.master  # the link that hears that system
                link.mav.command_long_send(msg.target_system, msg.target_component, msg.command,
                                           msg.confirmation, msg.param1, msg.param2, msg.param3,
                                           msg.param4, msg.param5, msg.param6, msg.param7)
                print(f"safer: {name} (opcode 0x{op:x}) sent to system {system}")
            else:
                print(USAGE)


def init(mpstate: Any) -> Any:
    """MAVProxy's entry point (``module load ground.mavproxy.safer``)."""
    if mp_module is None:
        raise ImportError("ground.mavproxy.safer is a MAVProxy module: load it from MAVProxy")
    return SaferModule(mpstate)
