"""The topology: which components exist, their classes, and their ids and opcodes.

One function, :func:`components`, resolves the schedule in the config into component
classes; the executive registers from it and ``safer-fsw dictionary`` prints from it, so
names and ids are never kept in a second table. Ids are assigned in declaration order:
component ``i`` gets command opcodes ``(i + 1) * 0x100 + j``.

:func:`check` refuses a schedule that cannot fly as written (``ConfigError``, one line): a
flight configuration (``[executive] flight = true``) without an enabled task of each of
:data:`FLIGHT_KINDS`, an unknown task kind, a task whose rate (``1 / (frame_period_s * divisor)``) lies outside its
kind's design range (``Task.RATE_HZ``), or a task scheduled without the kinds it needs
(``Task.required_kinds``: the mission needs motion, camera, perception, nbv, health and, when
it transmits, radio; motion needs the motor, mast and attitude devices; ...).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from fsw.executive.components import ExecutiveComponent, RateGroupComponent
from fsw.framework.params import ConfigError
from fsw.framework.task import Task
from fsw.settings import FswConfig
from fsw.tasks.registry import KINDS

#: what a flight configuration always schedules (the kinds these need are added by ``required_kinds``)
FLIGHT_KINDS = ("mission", "health", "console", "mavlink")


@dataclass(frozen=True)
class Component:
    name: str
    cls: type[Task]
    opcode_base: int


def task_class(kind: str, source: str = "config") -> type[Task]:
    """Resolve a task kind to its class (imported lazily); ``ConfigError`` for an unknown kind."""
    if kind not in KINDS:
        known = ", ".join(sorted(KINDS))
        raise ConfigError(source, "executive.tasks.kind", f"unknown task kind {kind!r} (known: {known})")
    module, _, attr = KINDS[kind].partition(":")
    cls = getattr(importlib.import_module(module), attr)
    if not (isinstance(cls, type) and issubclass(cls, Task)):
        raise TypeError(f"{KINDS[kind]} is not a Task")
    return cls


def check(cfg: FswConfig, source: str = "config") -> None:
    """Refuse a schedule with an unknown kind, a rate out of design range or a missing task."""
    ex = cfg.executive
    groups = {g.name: g for g in ex.groups}
    kinds = {t.kind for t in ex.tasks if t.enabled}
    missing = [k for k in FLIGHT_KINDS if k not in kinds] if ex.flight else []
    if missing:
        raise ConfigError(source, "executive.tasks", f"a flight configuration schedules an enabled task of kind "
                                                     f"{', '.join(repr(k) for k in missing)}")
    for i, t in enumerate(ex.tasks):
        key = f"executive.tasks[{i}]"
        cls = task_class(t.kind, source)
        lo, hi = cls.RATE_HZ
        rate_hz = 1.0 / (ex.frame_period_s * groups[t.group].divisor)
        if not lo <= rate_hz <= hi:
            raise ConfigError(source, key, f"task {t.name!r} ({t.kind}) would run at {rate_hz:g} Hz, "
                                           f"outside its design range {lo:g}-{hi:g} Hz")
        missing = [k for k in cls.required_kinds(cfg) if k not in kinds]
        if missing:
            raise ConfigError(source, key, f"task {t.name!r} ({t.kind}) needs a task of kind "
                                           f"{', '.join(repr(k) for k in missing)} in the schedule")


def components(cfg: FswConfig) -> list[Component]:
    """The executive, each rate group, then each configured task, in that order."""
    out = [Component("exec", ExecutiveComponent, 0x100)]
    for g in cfg.executive.groups:
        out.append(Component(f"rg_{g.name}", RateGroupComponent, (len(out) + 1) * 0x100))
    for t in cfg.executive.tasks:
        out.append(Component(t.name, task_class(t.kind), (len(out) + 1) * 0x100))
    return out


def dictionary(cfg: FswConfig) -> dict[str, object]:
    """The ground dictionary (channels, events, commands) generated from the declarations."""
    chans: list[dict[str, object]] = []
    events: list[dict[str, object]] = []
    cmds: list[dict[str, object]] = []
    for comp in components(cfg):
        for c in comp.cls.all_channels():
            chans.append(
                {
                    "id": len(chans) + 1,
                    "name": f"{comp.name}.{c.name}",
                    "units": c.units,
                    "lo": c.lo,
                    "hi": c.hi,
                    "doc": c.doc,
                }
            )
        for e in comp.cls.all_events():
            events.append(
                {
                    "id": len(events) + 1,
                    "name": f"{comp.name}.{e.name}",
                    "severity": e.severity.name,
                    "format": e.fmt,
                    "throttle": e.throttle,
                }
            )
        for j, cd in enumerate(comp.cls.all_commands()):
            cmds.append(
                {
                    "opcode": comp.opcode_base + j,
                    "name": f"{comp.name}.{cd.name}",
                    "doc": cd.doc,
                    "args": [
                        {
                            "name": a.name,
                            "type": a.kind.__name__,
                            "lo": a.lo,
                            "hi": a.hi,
                            "choices": list(a.choices) if a.choices else None,
                            "units": a.units,
                        }
                        for a in cd.args
                    ],
                }
            )
    return {"channels": chans, "events": events, "commands": cmds}
