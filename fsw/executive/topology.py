"""The topology: which components exist, their classes, and their ids and opcodes.

One function, :func:`components`, resolves the schedule in the config into component
classes; the executive registers from it and ``safer-fsw dictionary`` prints from it, so
names and ids are never kept in a second table. Ids are assigned in declaration order:
component ``i`` gets command opcodes ``(i + 1) * 0x100 + j``. The task kinds are those of the
configuration's agent (``[agent] kind``, :func:`agent_topology`; ``fsw.framework.agent``).

The schedule is checked first (:func:`fsw.schedule_check.check`, which the settings
loader runs on every file).
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.executive.components import ExecutiveComponent, RateGroupComponent
from fsw.framework.agent import AgentTopology
from fsw.framework.task import Task
from fsw.registry import AGENTS
from fsw.schedule_check import FLIGHT_KINDS, check, task_class
from fsw.settings import FswConfig

__all__ = ["FLIGHT_KINDS", "Component", "agent_topology", "check", "components", "dictionary", "task_class"]


@dataclass(frozen=True)
class Component:
    name: str
    cls: type[Task]
    opcode_base: int


def agent_topology(cfg: FswConfig) -> AgentTopology:
    """The topology of the configuration's agent (``[agent] kind``)."""
    kind = cfg.agent.kind
    if kind not in AGENTS:
        raise KeyError(f"unknown agent kind {kind!r} (known: {', '.join(sorted(AGENTS))})")
    return AGENTS[kind]


def components(cfg: FswConfig) -> list[Component]:
    """The executive, each rate group, then each configured task, in that order."""
    kinds = agent_topology(cfg).task_kinds
    out = [Component("exec", ExecutiveComponent, 0x100)]
    for g in cfg.executive.groups:
        out.append(Component(f"rg_{g.name}", RateGroupComponent, (len(out) + 1) * 0x100))
    for t in cfg.executive.tasks:
        out.append(Component(t.name, task_class(t.kind, kinds=kinds), (len(out) + 1) * 0x100))
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
