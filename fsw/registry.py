"""Task kinds by name -> ``module:Class``, imported lazily (python-can's backend registry), and
the agents built from them.

Add one line per task kind; ``[[executive.tasks]] kind = "..."`` in the config picks it. An
agent kind (``[agent] kind``) is a topology (``fsw.framework.agent.AgentTopology``): the task
kinds its schedule may use and the configuration sections it reads. A new agent is a new
entry in ``AGENTS`` with its task kinds (docs/architecture.md, "Agents").
"""

from fsw.framework.agent import AgentTopology

# Every agent may schedule these: health and watchdog, test tasks, the console, MAVLink.
COMMON_KINDS: dict[str, str] = {
    "health": "fsw.executive.health:HealthTask",
    "noop": "fsw.tasks.noop:NoopTask",
    "busy": "fsw.tasks.noop:BusyTask",
    "console": "fsw.tasks.console:ConsoleTask",
    "mavlink": "fsw.tasks.mavlink_task:MavlinkTask",
}

# The RECON-bot's own tasks: its devices, moves, stereo mapping, next view, mission, map link.
RECON_KINDS: dict[str, str] = {
    "can_motors_device": "fsw.tasks.devices:CanMotorsDevice",
    "imu_device": "fsw.tasks.devices:ImuDevice",
    "mast_device": "fsw.tasks.devices:MastDevice",
    "camera_device": "fsw.tasks.devices:CameraDevice",
    "motion": "fsw.tasks.motion:MotionTask",
    "radio": "fsw.tasks.radio_task:RadioTask",
    "camera": "fsw.tasks.camera:CameraTask",
    "perception": "fsw.tasks.perception:PerceptionTask",
    "nbv": "fsw.tasks.nbv:NbvTask",
    "mission": "fsw.tasks.mission:MissionTask",
    "cliffbot_fixer": "fsw.tasks.fixer.task:CliffbotFixerTask",
}

# The RECON-bot's task kinds (the common ones and its own); tests add their task kinds here.
KINDS: dict[str, str] = {**COMMON_KINDS, **RECON_KINDS}

RECON = AgentTopology(
    kind="recon",
    doc="RECON-bot: maps the cliff edge with its mast stereo camera and sends the map to the Cliff-bot",
    task_kinds=KINDS,
    sections=frozenset({
        "rover", "camera", "mast", "map", "stereo", "fusion", "registration", "localization", "cliffbot", "edge",
        "geofence", "checkpoint", "mavlink", "codec", "link", "nbv", "devices", "motion", "capture", "mission",
        "calibration", "cliffbot_site",  # the team's site: its mask, and the Anchorbots' plates for its fixer
        "map_sync",  # the team's two-way map sync (off unless a team mission turns it on)
    }),
)

# The Cliff-bot's own tasks (fsw/tasks/cliffbot/): its team bus, its radio, its mission.
CLIFFBOT_KINDS: dict[str, str] = {
    "cliffbot_devices": "fsw.tasks.cliffbot.devices:CliffbotDevicesTask",
    "cliffbot_radio": "fsw.tasks.cliffbot.radio:CliffbotRadioTask",
    "cliffbot_nav": "fsw.tasks.cliffbot.navigation:CliffbotNavTask",
    "cliffbot_mission": "fsw.tasks.cliffbot.mission:CliffbotMissionTask",
    "cliffbot_sensing": "fsw.tasks.cliffbot.sensing:CliffbotSensingTask",
}

CLIFFBOT = AgentTopology(
    kind="cliffbot",
    doc="Cliff-bot: lowered on two tethers, plans and drives to science targets on the map it received",
    task_kinds={**COMMON_KINDS, **CLIFFBOT_KINDS},
    sections=frozenset({
        "map", "link", "map_sync", "mavlink", "checkpoint", "tether", "climber", "cliffbot_nav", "cliffbot_mission",
        "cliffbot_site", "cliffbot_bus", "cliffbot_sensing",
    }),
    required_tasks=("cliffbot_mission",),
    flight_kinds=("cliffbot_mission", "health", "console", "mavlink"),
)

AGENTS: dict[str, AgentTopology] = {RECON.kind: RECON, CLIFFBOT.kind: CLIFFBOT}
