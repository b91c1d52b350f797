"""Task kinds by name -> ``module:Class``, imported lazily (python-can's backend registry).

Add one line per task kind; ``[[executive.tasks]] kind = "..."`` in the config picks it.
"""

KINDS: dict[str, str] = {
    "health": "fsw.executive.health:HealthTask",
    "noop": "fsw.tasks.noop:NoopTask",
    "busy": "fsw.tasks.noop:BusyTask",
    "console": "fsw.tasks.console:ConsoleTask",
    "mavlink": "fsw.tasks.mavlink_task:MavlinkTask",
}
