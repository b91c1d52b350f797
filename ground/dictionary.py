"""The ground's view of the flight dictionary: channel ids, limits, commands and budgets.

Built from the same flight configuration the rover runs (``--config``, default
config/fsw.toml) through ``fsw.executive.topology``, so names are never kept twice. The
rover sends the CRC of its channel table (``NAMED_VALUE_INT dict_crc``); a mismatch means
the ground decodes with another configuration and shows raw keys instead of wrong names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fsw.comm.mavlink_telemetry import dictionary_crc, parse_channel_key
from fsw.framework.commands import CommandDef
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings


@dataclass(frozen=True)
class ChannelInfo:
    id: int
    name: str
    units: str
    lo: float | None
    hi: float | None

    def limit_state(self, value: float) -> str:
        if self.lo is not None and value < self.lo:
            return "low"
        if self.hi is not None and value > self.hi:
            return "high"
        return "ok"


@dataclass
class GroundDictionary:
    cfg: FswConfig
    source: str
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    commands: dict[str, tuple[int, CommandDef]] = field(default_factory=dict)
    budgets_ms: dict[str, float] = field(default_factory=dict)
    crc: int = 0

    def command(self, spec: str) -> tuple[str, int, CommandDef]:
        """Resolve ``task.COMMAND`` (case-insensitive) or an opcode (``0x301``, ``769``)."""
        try:
            opcode = int(spec, 0)
        except ValueError:
            opcode = None
        for name, (op, cdef) in self.commands.items():
            if (opcode is not None and op == opcode) or name.lower() == spec.lower():
                return name, op, cdef
        raise KeyError(f"unknown command {spec!r} (see `safer-fsw dictionary`)")

    def channel_name(self, key: str, remote_crc: int | None) -> str:
        """The full channel name for a NAMED_VALUE key (the raw key if it cannot be trusted)."""
        cid = parse_channel_key(key)
        if cid is None or (remote_crc is not None and remote_crc != self.crc):
            return key
        info = self.channels.get(cid)
        return info.name if info is not None else key

    def by_name(self, name: str) -> ChannelInfo | None:
        for info in self.channels.values():
            if info.name == name:
                return info
        return None


def load_dictionary(path: str | Path = DEFAULT_CONFIG) -> GroundDictionary:
    """Raises ``fsw.framework.params.ConfigError`` for a bad file (CLIs print it and exit 2)."""
    from fsw.executive.topology import components

    cfg = load_settings(path)
    d = GroundDictionary(cfg, str(path))
    n = 0
    for comp in components(cfg):
        for ch in comp.cls.all_channels():
            n += 1
            d.channels[n] = ChannelInfo(n, f"{comp.name}.{ch.name}", ch.units, ch.lo, ch.hi)
        for j, cd in enumerate(comp.cls.all_commands()):
            d.commands[f"{comp.name}.{cd.name}"] = (comp.opcode_base + j, cd)
    d.budgets_ms = {t.name: t.budget_ms for t in cfg.executive.tasks}
    d.crc = dictionary_crc((i, c.name) for i, c in d.channels.items())
    return d
