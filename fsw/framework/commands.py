"""Commands declared as data, validated and answered exactly once.

Every request gets one :class:`CommandResponse`: ``OK``, ``VALIDATION_ERROR`` (unknown
command, missing/unknown/ill-typed/out-of-range argument) or ``EXECUTION_ERROR`` (the
handler refused or failed). A handler that raises an unexpected exception is an
``EXECUTION_ERROR`` with an event, never a crash (F Prime command dispatcher).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any


class CommandStatus(Enum):
    OK = "OK"
    VALIDATION_ERROR = "VALIDATION_ERROR"
    EXECUTION_ERROR = "EXECUTION_ERROR"


class CommandError(Exception):
    """Raised by a handler to answer EXECUTION_ERROR with a reason."""


@dataclass(frozen=True)
class Arg:
    """A command argument: ``kind`` is one of int, float, bool, str."""

    name: str
    kind: type = float
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] | None = None
    units: str = ""
    doc: str = ""

    def validate(self, value: Any) -> Any:
        """Return the value converted to ``kind`` or raise ``ValueError`` with the reason."""
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ValueError(f"{self.name}: expected true/false, got {value!r}")
        elif self.kind is int:
            if isinstance(value, bool) or not (
                isinstance(value, int) or (isinstance(value, float) and value.is_integer())
            ):
                raise ValueError(f"{self.name}: expected an integer, got {value!r}")
            value = int(value)
        elif self.kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
                raise ValueError(f"{self.name}: expected a number, got {value!r}")
            value = float(value)
        elif self.kind is str and not isinstance(value, str):
            raise ValueError(f"{self.name}: expected a string, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ValueError(f"{self.name}: must be one of {list(self.choices)}, got {value!r}")
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if self.lo is not None and value < self.lo:
                raise ValueError(f"{self.name}: {value} is below the minimum {self.lo}")
            if self.hi is not None and value > self.hi:
                raise ValueError(f"{self.name}: {value} is above the maximum {self.hi}")
        return value


@dataclass(frozen=True)
class CommandDef:
    """A command declaration; the handler is the owning task's method ``cmd_<name>``."""

    name: str
    args: tuple[Arg, ...] = ()
    doc: str = ""


@dataclass(frozen=True)
class CommandRequest:
    name: str  # full name, ``task.COMMAND``
    args: Mapping[str, Any]
    seq: int = 0
    source: str = "ground"


@dataclass(frozen=True)
class CommandResponse:
    name: str
    seq: int
    status: CommandStatus
    message: str = ""


@dataclass(frozen=True)
class _Entry:
    opcode: int
    definition: CommandDef
    handler: Callable[..., Any]


class CommandDispatcher:
    """Routes requests to handlers; counts what it dispatched and what it refused."""

    def __init__(self, on_response: Callable[[CommandRequest, CommandResponse], None] | None = None) -> None:
        self._entries: dict[str, _Entry] = {}
        self._by_opcode: dict[int, str] = {}
        self.on_response = on_response
        self.dispatched = 0
        self.errors = 0

    def register(self, full_name: str, opcode: int, cdef: CommandDef, handler: Callable[..., Any]) -> None:
        if full_name in self._entries:
            raise ValueError(f"command {full_name} declared twice")
        if opcode in self._by_opcode:
            raise ValueError(f"opcode {opcode:#x} of {full_name} already used by {self._by_opcode[opcode]}")
        self._entries[full_name] = _Entry(opcode, cdef, handler)
        self._by_opcode[opcode] = full_name

    def definitions(self) -> dict[str, tuple[int, CommandDef]]:
        return {k: (e.opcode, e.definition) for k, e in self._entries.items()}

    def name_of(self, opcode: int) -> str | None:
        return self._by_opcode.get(opcode)

    def dispatch(self, req: CommandRequest) -> CommandResponse:
        """Validate and run one command; always returns exactly one response."""
        resp = self._dispatch(req)
        self.dispatched += 1
        if resp.status is not CommandStatus.OK:
            self.errors += 1
        if self.on_response is not None:
            self.on_response(req, resp)
        return resp

    def _dispatch(self, req: CommandRequest) -> CommandResponse:
        def answer(status: CommandStatus, msg: str = "") -> CommandResponse:
            return CommandResponse(req.name, req.seq, status, msg)

        entry = self._entries.get(req.name)
        if entry is None:
            return answer(CommandStatus.VALIDATION_ERROR, f"unknown command {req.name!r}")
        if not isinstance(req.args, Mapping):
            return answer(CommandStatus.VALIDATION_ERROR, "arguments must be a mapping")
        declared = {a.name: a for a in entry.definition.args}
        unknown = sorted(set(req.args) - set(declared))
        if unknown:
            return answer(CommandStatus.VALIDATION_ERROR, f"unknown argument {unknown[0]!r}")
        kwargs: dict[str, Any] = {}
        for name, arg in declared.items():
            if name not in req.args:
                return answer(CommandStatus.VALIDATION_ERROR, f"missing argument {name!r}")
            try:
                kwargs[name] = arg.validate(req.args[name])
            except ValueError as exc:
                return answer(CommandStatus.VALIDATION_ERROR, str(exc))
        try:
            result = entry.handler(**kwargs)
        except CommandError as exc:
            return answer(CommandStatus.EXECUTION_ERROR, str(exc))
        except Exception as exc:  # noqa: BLE001 - a handler bug must not take the executive down
            return answer(CommandStatus.EXECUTION_ERROR, f"handler failed: {type(exc).__name__}: {exc}")
        return answer(CommandStatus.OK, "" if result is None else str(result))
