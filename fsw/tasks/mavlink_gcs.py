"""What a stock ground station asks of a vehicle, answered for the ground-link task (docs/ground.md).

* Polls (COMMAND_LONG other than the dictionary's MAV_CMD_USER_1, signed or not): HOME_POSITION
  (MAV_CMD_GET_HOME_POSITION, or MAV_CMD_REQUEST_MESSAGE 242) is the mission's origin, the
  world frame of LOCAL_POSITION_NED; AUTOPILOT_VERSION (MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
  or REQUEST_MESSAGE 148) says which protocols are served; anything else is answered
  MAV_RESULT_UNSUPPORTED. Polls are counted (``polls``, ``polls_unsupported``), never evented.
* PARAM protocol (``fsw.comm.mavlink_params``): PARAM_REQUEST_LIST and PARAM_REQUEST_READ need
  no key; PARAM_SET must be signed and recorded in the replay window like a command. A set is
  validated by the config file's rules (type, range, choices, the section's cross checks),
  applied at once for the keys in :data:`RUNTIME_KEYS` (the ground link's own rates and
  budgets) and refused with a reason for every other key (read at start-up: edit the
  config file). The answer is PARAM_VALUE with the value in force (so a refused set reads
  back unchanged), and PARAM_ERROR with the reason's code for a refusal.
* MISSION/FENCE protocol (``fsw.comm.mavlink_mission``): the latest plan the mission published.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable

from fsw.comm import mavlink_mission as mm
from fsw.comm import mavlink_params as mp
from fsw.comm.mavlink_adapter import MavlinkAdapter
from fsw.comm.mavlink_config import MavlinkConfig
from fsw.comm.mavlink_dialect import mavlink
from fsw.comm.mavlink_plan import GroundPlan
from fsw.comm.mavlink_signing import Verdict
from fsw.comm.mavlink_uplink import CommandIn, GcsRequest
from fsw.framework.params import ConfigError, check_field
from fsw.settings import FswConfig

#: keys of ``[mavlink]`` a PARAM_SET applies at run time; every other key is refused
RUNTIME_KEYS = frozenset({
    "heartbeat_period_s", "sys_status_period_s", "pose_period_s", "mast_period_s", "channel_period_s",
    "channel_refresh_s", "statustext_rate_hz", "statustext_burst", "image_period_s", "budget_bytes_per_frame",
    "gcs_timeout_s", "denial_acks_per_s", "replies_per_s", "auth_event_period_s", "commands_per_frame",
})
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE)
_REQUEST_MESSAGE = {mavlink.MAVLINK_MSG_ID_HOME_POSITION: "home", mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: "version"}


class GcsServices:
    """Answers polls, the PARAM and the MISSION protocols through ``adapter`` (rate-limited replies)."""

    def __init__(self, root_cfg: FswConfig, adapter: MavlinkAdapter, apply: Callable[[MavlinkConfig], None]) -> None:
        self.root, self.adapter, self.apply = root_cfg, adapter, apply
        self.table = mp.build_table(root_cfg)
        self.by_id = {p.pid: p for p in self.table}
        self.plan = GroundPlan()
        self._listing: deque[mp.Param] = deque()  # a PARAM_REQUEST_LIST's parameters not yet queued
        self.counts = {"polls": 0, "polls_unsupported": 0, "param_sets": 0, "param_refused": 0, "requests": 0}

    # -- polls ------------------------------------------------------------------------------
    def poll(self, cmd: CommandIn, now: float) -> None:
        """A COMMAND_LONG that is not the dictionary's: the standard answer or UNSUPPORTED."""
        self.counts["polls"] += 1
        what = None
        if cmd.command_id == mavlink.MAV_CMD_GET_HOME_POSITION:
            what = "home"
        elif cmd.command_id == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            what = "version"
        elif cmd.command_id == mavlink.MAV_CMD_REQUEST_MESSAGE and cmd.param1 in _REQUEST_MESSAGE:
            what = _REQUEST_MESSAGE[int(cmd.param1)]
        ack = mavlink.MAVLink_command_ack_message(
            cmd.command_id, mavlink.MAV_RESULT_ACCEPTED if what else mavlink.MAV_RESULT_UNSUPPORTED, 0, 0,
            cmd.src_system, cmd.src_component)
        if what is None:
            self.counts["polls_unsupported"] += 1
            self.adapter.reply(now, [ack])
            return
        self.adapter.reply(now, [ack, self.home() if what == "home" else self.version()])

    @staticmethod
    def home() -> mavlink.MAVLink_home_position_message:
        """The mission's origin: local (0, 0, 0), level; no GPS (latitude/longitude 0)."""
        return mavlink.MAVLink_home_position_message(0, 0, 0, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    @staticmethod
    def version() -> mavlink.MAVLink_autopilot_version_message:
        return mavlink.MAVLink_autopilot_version_message(CAPABILITIES, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)

    # -- PARAM and MISSION ----------------------------------------------------------------------
    def request(self, req: GcsRequest, now: float, recorded: bool) -> str | None:
        """Answer one request; ``recorded``: a signed PARAM_SET whose timestamp is on disk.
        Returns an event text for a PARAM_SET (applied or refused), else None."""
        self.counts["requests"] += 1
        msg, target = req.msg, (req.src_system, req.src_component)
        kind = req.kind
        if kind == "PARAM_REQUEST_LIST":
            self.adapter.param_stream.clear()  # a repeated request restarts the list: bounded by the table
            self._listing = deque(self.table)
        elif kind == "PARAM_REQUEST_READ":
            p = self._find(msg.param_id, msg.param_index)
            if p is None:
                raw = mp.decode_id(msg.param_id).encode()
                self.adapter.reply(now, [mavlink.MAVLink_param_error_message(
                    *target, raw, msg.param_index, mavlink.MAV_PARAM_ERROR_DOES_NOT_EXIST)])
            else:
                self.adapter.reply(now, [self._value(p)])
        elif kind == "PARAM_SET":
            return self._set(req, now, target, recorded)
        elif kind == "MISSION_REQUEST_LIST":
            self.adapter.reply(now, [mm.count(self.plan, msg.mission_type, target)])
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self.adapter.reply(now, [mm.item(self.plan, msg.mission_type, msg.seq, target)])
        return None

    def top_up(self, n: int = 12) -> None:
        """Keep ``n`` PARAM_VALUEs of a list in progress ready for the downlink: built as they
        go (a pymavlink message costs ~0.07 ms; the whole list at once overran the task)."""
        stream = self.adapter.param_stream
        while self._listing and len(stream) < n:
            stream.append(self._value(self._listing.popleft()))

    def _find(self, raw_id: bytes | str, index: int) -> mp.Param | None:
        if 0 <= index < len(self.table):
            return self.table[index]
        return self.by_id.get(mp.decode_id(raw_id))

    def _value(self, p: mp.Param) -> mavlink.MAVLink_param_value_message:
        return mp.param_value(p, mp.value_of(self.root, p), len(self.table))

    def _set(self, req: GcsRequest, now: float, target: tuple[int, int], recorded: bool) -> str | None:
        pid = mp.decode_id(req.msg.param_id)
        p = self.by_id.get(pid)
        if p is None:
            self.adapter.reply(now, [mavlink.MAVLink_param_error_message(
                *target, pid.encode(), -1, mavlink.MAV_PARAM_ERROR_DOES_NOT_EXIST)])
            return None if req.verdict is not Verdict.OK else f"PARAM_SET {pid!r} refused: no such parameter"
        if req.verdict is not Verdict.OK:  # counted by the caller with the other refusals
            self.adapter.reply(now, [self._value(p)])
            return None
        error, reason = mavlink.MAV_PARAM_ERROR_NO_ERROR, ""
        if not recorded:
            error, reason = mavlink.MAV_PARAM_ERROR_PERMISSION_DENIED, "replay window not saved"
        elif p.path[0] != "mavlink" or len(p.path) != 2 or p.path[1] not in RUNTIME_KEYS:
            error, reason = mavlink.MAV_PARAM_ERROR_READ_ONLY, "read at start-up only: edit the config file"
        else:
            try:
                value = mp.from_wire(p, float(req.msg.param_value))
                section = self.root.mavlink
                check_field(type(section), p.path[1], value, "PARAM_SET", p.key)
                new = dataclasses.replace(section, **{p.path[1]: value})
            except (ConfigError, ValueError, TypeError) as exc:
                error, reason = mavlink.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, str(exc)
            else:
                self.root = dataclasses.replace(self.root, mavlink=new)
                self.apply(new)
        replies: list[mavlink.MAVLink_message] = [self._value(p)]
        if error:
            replies.insert(0, mavlink.MAVLink_param_error_message(*target, pid.encode(), p.index, error))
        self.adapter.reply(now, replies)
        self.counts["param_refused" if error else "param_sets"] += 1
        shown = mp.value_of(self.root, p)
        return f"{p.pid} ({p.key}) = {shown}" if not error else f"{p.pid} ({p.key}) refused: {reason}"

