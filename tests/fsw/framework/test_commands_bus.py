"""Issue 2, items 8 and 9: commands answered exactly once; bounded queues drop, count, event."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, ClassVar

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw import registry
from fsw.executive.executive import Executive
from fsw.framework.bus import Mailbox
from fsw.framework.clock import SteppedClock
from fsw.framework.commands import Arg, CommandDef, CommandError, CommandRequest, CommandStatus
from fsw.framework.params import build
from fsw.framework.task import Task
from fsw.settings import FswConfig


class ArmTask(Task):
    KIND: ClassVar[str] = "test_arm"
    COMMANDS = (
        CommandDef("POINT", (Arg("pan_deg", float, lo=-170, hi=170), Arg("mode", str, choices=("abs", "rel")))),
        CommandDef("FAIL"),
        CommandDef("CRASH"),
    )

    def setup(self) -> None:
        self.pointed: list[tuple[float, str]] = []

    def cmd_POINT(self, pan_deg: float, mode: str) -> None:
        self.pointed.append((pan_deg, mode))

    def cmd_FAIL(self) -> None:
        raise CommandError("mast is stowed")

    def cmd_CRASH(self) -> None:
        raise ZeroDivisionError("bug")


@pytest.fixture(autouse=True, scope="module")
def _arm_kind() -> Iterator[None]:
    """The test kind is known to the registry for this module only (``registry.KINDS`` is restored)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(registry.KINDS, "test_arm", f"{__name__}:ArmTask")
        yield


def make() -> Executive:
    cfg = build(
        FswConfig,
        {
            "executive": {
                "groups": [{"name": "g", "divisor": 1}],
                "tasks": [{"name": "arm", "kind": "test_arm", "group": "g", "budget_ms": 5}],
            }
        },
        "<t>",
    )
    return Executive(cfg, SteppedClock())


def test_every_command_path_answers_exactly_once() -> None:
    exe = make()
    answers: list[Any] = []
    exe.commands.on_response = lambda req, resp, _orig=exe.commands.on_response: (
        answers.append(resp),
        _orig(req, resp),
    )
    cases = [
        (CommandRequest("arm.POINT", {"pan_deg": 10.0, "mode": "abs"}, 1), CommandStatus.OK),
        (CommandRequest("arm.POINT", {"pan_deg": 500.0, "mode": "abs"}, 2), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.POINT", {"pan_deg": "x", "mode": "abs"}, 3), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.POINT", {"mode": "abs"}, 4), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.POINT", {"pan_deg": 1, "mode": "abs", "x": 1}, 5), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.POINT", {"pan_deg": 1, "mode": "up"}, 6), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.NOPE", {}, 7), CommandStatus.VALIDATION_ERROR),
        (CommandRequest("arm.FAIL", {}, 8), CommandStatus.EXECUTION_ERROR),
        (CommandRequest("arm.CRASH", {}, 9), CommandStatus.EXECUTION_ERROR),
        (CommandRequest("arm.NOOP", {}, 10), CommandStatus.OK),
        (CommandRequest("nosuch.NOOP", {}, 11), CommandStatus.VALIDATION_ERROR),
    ]
    for req, expected in cases:
        resp = exe.commands.dispatch(req)
        assert resp.status is expected, (req, resp)
        assert resp.seq == req.seq
    assert [a.seq for a in answers] == [r.seq for r, _ in cases]  # once each, in order
    arm = exe.tasks["arm"]
    assert arm.pointed == [(10.0, "abs")]
    assert arm.cmd_count == 2 and arm.cmd_errors == 8
    assert exe.events.count("arm.COMMAND_REFUSED") == 8
    assert exe.events.count("arm.NOOP") == 1
    r = exe.commands.dispatch(CommandRequest("arm.RESET_COUNTERS", {}))
    assert r.status is CommandStatus.OK and arm.cmd_errors == 0


@settings(max_examples=200, deadline=None)
@given(
    name=st.sampled_from(["arm.POINT", "arm.NOOP", "arm.FAIL", "exec.SET_TASK_ENABLED", "x", ""]),
    args=st.dictionaries(
        st.text(max_size=8),
        st.one_of(st.none(), st.integers(), st.floats(), st.text(max_size=5), st.booleans()),
        max_size=3,
    ),
)
def test_fuzzed_commands_always_get_one_answer(name: str, args: dict[str, Any]) -> None:
    """Any request, however malformed, gets exactly one response and no exception."""
    exe = make()
    before = exe.commands.dispatched
    resp = exe.commands.dispatch(CommandRequest(name, args))
    assert exe.commands.dispatched == before + 1
    assert resp.status in CommandStatus


def test_full_queue_drops_counts_and_events() -> None:
    exe = make()
    newest = exe.bus.subscribe("img", "a", depth=2, policy="drop_newest")
    oldest = exe.bus.subscribe("img", "b", depth=2, policy="drop_oldest")
    for i in range(5):
        exe.bus.publish("img", i)
    assert newest.drain() == [0, 1] and newest.dropped == 3
    assert oldest.drain() == [3, 4] and oldest.dropped == 3
    assert exe.events.count("exec.QUEUE_FULL") == 6
    exe.step()
    assert exe.telemetry.get("exec.bus_drops") == 6


def test_mailbox_rejects_bad_settings() -> None:
    import pytest

    with pytest.raises(ValueError):
        Mailbox("x", 0)
    with pytest.raises(ValueError):
        Mailbox("x", 1, policy="grow")  # type: ignore[arg-type]
