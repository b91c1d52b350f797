"""Task kinds by name -> ``module:Class``, imported lazily (python-can's backend registry).

Add one line per task kind; ``[[executive.tasks]] kind = "..."`` in the config picks it.
"""

KINDS: dict[str, str] = {
    "health": "fsw.executive.health:HealthTask",
    "noop": "fsw.tasks.noop:NoopTask",
    "busy": "fsw.tasks.noop:BusyTask",
    "console": "fsw.tasks.console:ConsoleTask",
    "mavlink": "fsw.tasks.mavlink_task:MavlinkTask",
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
}
