"""The schedule checked before anything is built: kinds known, rates in range, needs met.

:func:`check` refuses a schedule that cannot fly as written (``ConfigError``, one line): a
flight configuration (``[executive] flight = true``) without an enabled task of each of
:data:`FLIGHT_KINDS`, an unknown task kind, a task whose rate (``1 / (frame_period_s *
divisor)``) lies outside its kind's design range (``Task.RATE_HZ``), or a task scheduled
without the kinds it needs (``Task.required_kinds``: the mission needs motion, camera,
perception, nbv, health and, when it transmits, radio; motion needs the motor, mast and
attitude devices; ...). ``fsw.settings.load_settings`` runs it on every file it loads, so it
knows the configuration only by the shape it reads (:class:`ScheduledConfig`).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Protocol

from fsw.framework.agent import AgentConfig
from fsw.framework.params import ConfigError
from fsw.framework.schedule import ExecutiveConfig
from fsw.framework.task import Task
from fsw.registry import AGENTS, KINDS


class ScheduledConfig(Protocol):
    """What the check reads of the flight configuration (``fsw.settings.FswConfig``)."""

    @property
    def executive(self) -> ExecutiveConfig: ...

    @property
    def agent(self) -> AgentConfig: ...


#: what a flight configuration always schedules (the kinds these need are added by ``required_kinds``)
FLIGHT_KINDS = ("mission", "health", "console", "mavlink")


def task_class(kind: str, source: str = "config", kinds: Mapping[str, str] = KINDS) -> type[Task]:
    """Resolve a task kind to its class (imported lazily) among ``kinds`` (an agent's; all by
    default); ``ConfigError`` for an unknown kind."""
    if kind not in kinds:
        known = ", ".join(sorted(kinds))
        raise ConfigError(source, "executive.tasks.kind", f"unknown task kind {kind!r} (known: {known})")
    module, _, attr = kinds[kind].partition(":")
    cls = getattr(importlib.import_module(module), attr)
    if not (isinstance(cls, type) and issubclass(cls, Task)):
        raise TypeError(f"{kinds[kind]} is not a Task")
    return cls


def check(cfg: ScheduledConfig, source: str = "config") -> None:
    """Refuse a schedule with an unknown kind, a rate out of design range or a missing task."""
    ex = cfg.executive
    topo = AGENTS.get(cfg.agent.kind)
    agent_kinds = topo.task_kinds if topo is not None else KINDS  # an unknown agent: check_agent says so
    groups = {g.name: g for g in ex.groups}
    kinds = {t.kind for t in ex.tasks if t.enabled}
    must = topo.flight_kinds if topo is not None and topo.flight_kinds is not None else FLIGHT_KINDS
    missing = [k for k in must if k not in kinds] if ex.flight else []
    if missing:
        raise ConfigError(source, "executive.tasks", f"a flight configuration schedules an enabled task of kind "
                                                     f"{', '.join(repr(k) for k in missing)}")
    for i, t in enumerate(ex.tasks):
        key = f"executive.tasks[{i}]"
        cls = task_class(t.kind, source, agent_kinds)
        lo, hi = cls.RATE_HZ
        rate_hz = 1.0 / (ex.frame_period_s * groups[t.group].divisor)
        if not lo <= rate_hz <= hi:
            raise ConfigError(source, key, f"task {t.name!r} ({t.kind}) would run at {rate_hz:g} Hz, "
                                           f"outside its design range {lo:g}-{hi:g} Hz")
        missing = [k for k in cls.required_kinds(cfg) if k not in kinds]
        if missing:
            raise ConfigError(source, key, f"task {t.name!r} ({t.kind}) needs a task of kind "
                                           f"{', '.join(repr(k) for k in missing)} in the schedule")


def check_agent(cfg: ScheduledConfig, sections: set[str], source: str = "config") -> None:
    """The configuration fits its agent's topology (``[agent] kind``; ``fsw.registry.AGENTS``):
    a known kind, only the sections that agent reads, only its task kinds; ``ConfigError`` if not."""
    topo = AGENTS.get(cfg.agent.kind)
    if topo is None:
        known = ", ".join(sorted(AGENTS))
        raise ConfigError(source, "agent.kind", f"unknown agent kind {cfg.agent.kind!r} (known: {known})")
    try:
        topo.check_sections(sections)
    except ValueError as err:
        raise ConfigError(source, "agent", str(err)) from None
    try:
        topo.check_tasks([t.kind for t in cfg.executive.tasks])
    except ValueError as err:
        raise ConfigError(source, "executive.tasks", str(err)) from None
