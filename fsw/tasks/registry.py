"""Task kinds by name -> ``module:Class``, imported lazily (python-can's backend registry).

Add one line per task kind; ``[[executive.tasks]] kind = "..."`` in the config picks it.
"""

KINDS: dict[str, str] = {
    "health": "fsw.executive.health:HealthTask",
    "noop": "fsw.tasks.noop:NoopTask",
    "busy": "fsw.tasks.noop:BusyTask",
    "console": "fsw.tasks.console:ConsoleTask",
    "mavlink": "fsw.tasks.mavlink_task:MavlinkTask",
    "devices": "fsw.tasks.devices:DevicesTask",
    "motion": "fsw.tasks.motion:MotionTask",
    "radio": "fsw.tasks.radio_task:RadioTask",
    "camera": "fsw.tasks.camera:CameraTask",
    "perception": "fsw.tasks.perception:PerceptionTask",
    "nbv": "fsw.tasks.nbv:NbvTask",
    "mission": "fsw.tasks.mission:MissionTask",
}
