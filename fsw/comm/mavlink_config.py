"""Configuration of the MAVLink ground link (``[mavlink]`` in config/fsw.toml).

Kept free of pymavlink imports so that loading the flight configuration stays cheap.
Documented for operators in docs/ground.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fsw.framework.params import param

SEVERITY_NAMES = ("FATAL", "WARNING_HI", "WARNING_LO", "COMMAND", "ACTIVITY_HI", "ACTIVITY_LO", "DIAGNOSTIC")
_URL = re.compile(r"^(udpin|udpout):[^:]+:\d{1,5}$|^serial:.+$")


@dataclass(frozen=True)
class MavlinkConfig:
    """The MAVLink 2 ground link: transport, ids, signing, downlink budget and rates."""

    url: str = param("udpout:127.0.0.1:14550",
                     doc="udpin:HOST:PORT (listen; answer whoever sends), udpout:HOST:PORT "
                         "(send to a ground station) or serial:DEVICE")
    baud: int = param(57600, lo=1200, hi=4000000, units="bit/s", doc="serial line rate (serial: only)")
    system_id: int = param(1, lo=1, hi=255, doc="MAVLink system id of the rover")
    component_id: int = param(1, lo=1, hi=255, doc="MAVLink component id (1 = MAV_COMP_ID_AUTOPILOT1)")
    key_file: str = param("", doc="file with the 32-byte signing key (64 hex digits); never in the "
                                  "repository. Empty: no key, every command is refused")
    link_id: int = param(0, lo=0, hi=255, doc="signing link id of our outgoing frames")
    sign_downlink: bool = param(True, doc="sign outgoing frames too (13 bytes each) when a key is loaded")
    signing_max_age_s: float = param(60.0, lo=1.0, hi=86400.0, units="s",
                                     doc="a new signed stream older than this is refused as stale")
    signing_max_future_s: float = param(60.0, lo=0.1, hi=86400.0, units="s",
                                        doc="a signed command dated further ahead of our clock is refused "
                                            "(FUTURE), counted and evented")
    signing_state_file: str = param("", doc="where the replay window (newest timestamp per signed stream) "
                                            "is saved atomically to survive restarts; '' = KEY_FILE.replay.json "
                                            "next to the key (the window belongs to the key)")
    signing_reserve_s: float = param(5.0, lo=0.01, hi=3600.0, units="s",
                                     doc="the saved replay window runs this far ahead of the newest signed "
                                         "command, so it is written about once per this period whatever the "
                                         "command rate; after a restart a stream's commands are refused for "
                                         "at most this long after its last one")
    commands_per_frame: int = param(20, lo=1, hi=10000,
                                    doc="authenticated commands executed per activation; more are answered "
                                        "TEMPORARILY_REJECTED (a signed flood cannot starve the executive)")
    denial_acks_per_s: float = param(2.0, lo=0.1, hi=1000.0, units="Hz",
                                     doc="COMMAND_ACKs (DENIED) per second for commands that failed "
                                         "authentication; beyond, counted (acks_suppressed) and not sent")
    replies_per_s: float = param(50.0, lo=1.0, hi=10000.0, units="Hz",
                                 doc="answers per second to requests that need no key (polls, "
                                     "PARAM_REQUEST_READ, MISSION_*); beyond, counted and not sent")
    auth_event_period_s: float = param(10.0, lo=0.1, hi=3600.0, units="s",
                                       doc="refused commands are reported by at most one AUTH_REJECTED "
                                           "event per period, with their count")
    budget_bytes_per_frame: int = param(600, lo=280, hi=1_000_000, units="B",
                                        doc="downlink bytes per activation of the task, all frames "
                                            "included (>= one maximal 280-byte frame)")
    heartbeat_period_s: float = param(1.0, lo=0.1, hi=10.0, units="s", doc="HEARTBEAT period")
    sys_status_period_s: float = param(1.0, lo=0.1, hi=60.0, units="s", doc="SYS_STATUS period")
    pose_period_s: float = param(0.2, lo=0.05, hi=60.0, units="s",
                                 doc="LOCAL_POSITION_NED + ATTITUDE period")
    mast_period_s: float = param(0.5, lo=0.05, hi=60.0, units="s",
                                 doc="mast attitude (GIMBAL_DEVICE_ATTITUDE_STATUS) period")
    channel_period_s: float = param(1.0, lo=0.05, hi=3600.0, units="s",
                                    doc="a channel is sent at most this often (NAMED_VALUE_*)")
    channel_refresh_s: float = param(5.0, lo=0.1, hi=3600.0, units="s",
                                     doc="an unchanged channel is re-sent this often")
    statustext_rate_hz: float = param(5.0, lo=0.1, hi=100.0, units="Hz",
                                      doc="sustained events per second sent as STATUSTEXT")
    statustext_burst: int = param(10, lo=1, hi=1000, doc="events that may go back to back")
    statustext_queue: int = param(32, lo=1, hi=10000,
                                  doc="events waiting for the link; beyond, the least severe are "
                                      "dropped and counted")
    statustext_min_severity: str = param("ACTIVITY_LO", choices=SEVERITY_NAMES,
                                         doc="least severe event sent as STATUSTEXT")
    mission_state_channel: str = param("mission.state",
                                       doc="channel whose value sets the HEARTBEAT mode fields")
    pose_topic: str = param("nav.pose", doc="bus topic of the pose estimate (x, y, yaw rad; joints = pan, "
                                            "tilt rad, lift m); preferred over pose_channels once heard")
    pose_channels: tuple[str, ...] = param(
        ("motion.odo_x_m", "motion.odo_y_m", "", "", "", "motion.odo_yaw_deg"),
        doc="rover pose x, y, z (world, z up), roll, pitch, yaw (CCW from +x); '' = not available; "
            "angles in rad, or deg when the channel's units say so")
    mast_channels: tuple[str, ...] = param(("mast_drv.pan_deg", "mast_drv.tilt_deg"),
                                           doc="mast pan (CCW +) and tilt (up +) channels")
    map_preview_topic: str = param("map.updated",
                                   doc="bus topic with map previews sent by image transfer: the "
                                       "perception task's map updates, or 2-D arrays (float "
                                       "elevation, NaN unknown, or uint8 image)")
    plan_topic: str = param("mission.plan", doc="bus topic of the mission's plan (planned stations and "
                                                "geofence, fsw.comm.mavlink_mission.GroundPlan) served by "
                                                "the MISSION/FENCE protocol")
    image_period_s: float = param(10.0, lo=0.1, hi=3600.0, units="s",
                                  doc="at most one new map preview transfer per this period")
    image_max_px: int = param(128, lo=8, hi=1024, units="px", doc="longest side of a preview")
    image_quality: int = param(60, lo=1, hi=100, doc="JPEG quality of previews")
    gcs_timeout_s: float = param(5.0, lo=0.5, hi=600.0, units="s",
                                 doc="no ground HEARTBEAT for this long = link lost")
    rx_max_bytes_per_frame: int = param(16384, lo=280, hi=10_000_000, units="B",
                                        doc="uplink bytes read per activation (bounds its time)")
    tlog_path: str = param("", doc="write every frame sent and received to this .tlog ('' = off)")

    def __post_init__(self) -> None:
        if not _URL.match(self.url):
            raise ValueError(f"url {self.url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE")
        if self.url.startswith("udp") and not 0 < int(self.url.rsplit(":", 1)[1]) < 65536:
            raise ValueError(f"url {self.url!r}: port out of range")
        if len(self.pose_channels) != 6:
            raise ValueError("pose_channels needs 6 entries: x, y, z, roll, pitch, yaw ('' = absent)")
        if len(self.mast_channels) != 2:
            raise ValueError("mast_channels needs 2 entries: pan, tilt ('' = absent)")
        if self.channel_refresh_s < self.channel_period_s:
            raise ValueError("channel_refresh_s must be at least channel_period_s")
