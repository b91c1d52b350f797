"""Issue 5: the mission sequencer end to end in lockstep; SAFE on faults. (Determinism, the same seed
giving the same summary: test_map_preview_mission.py, beside the tests that share its mission.)"""

from __future__ import annotations

import dataclasses
from typing import Any

from fsw.settings import load_settings
from fsw.tasks.messages import MOTION_REQUEST
from hil_sim.mission.mission_run import RunSpec, mission_config


def test_mast_stall_sends_mission_to_safe() -> None:
    """Issue 5, item 4: a driver fault (stalled mast) ends in SAFE with an event, motors stopped."""
    from hil_sim.bench import LockstepBench
    from hil_sim.faults import FaultSpec
    from hil_sim.world import load_scenario

    world = load_scenario("lab", seed=0)
    cfg = mission_config(RunSpec("lab", "5", steps=2, seed=0, transmit=False), world)
    cfg = dataclasses.replace(cfg, motion=dataclasses.replace(cfg.motion, mast_timeout_s=3.0))
    with LockstepBench(cfg, world, seed=0, quiet=True, faults=(FaultSpec(kind="mast_stall"),)) as b:
        mission = b.exe.tasks["mission"]
        b.run_until(lambda: mission.state == "SAFE", 400)
        assert any("SAFE mode" in e.text for e in b.events("mission.SAFE"))
        assert b.tlm("mission.safe_entries") == 1
        r = b.command("mission.RESUME")
        assert r.status.name == "OK"
        r = b.command("mission.START")
        assert r.status.name == "EXECUTION_ERROR"  # already running


def _phase(b: Any) -> str:
    """The mission's phase by name (a plain string today, an Enum's name once phases are typed)."""
    state = b.exe.tasks["mission"].state
    return str(getattr(state, "name", state))


def test_mission_commands_validated() -> None:
    """Every mission command is answered exactly once with the one right status, and leaves the
    sequencer in the one right phase: START only from IDLE/DONE, ABORT only while running (-> SAFE,
    motion stopped), RESUME only from SAFE (nothing mapped yet: back to INIT)."""
    from hil_sim.bench import LockstepBench

    cfg = load_settings()
    cfg = dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, auto_start=False))
    with LockstepBench(cfg, None, seed=0, quiet=True, camera=False) as b:
        b.run(2)
        mission = b.exe.tasks["mission"]
        assert _phase(b) == "IDLE" and mission.safe.entries == 0
        steps = [
            ("RESUME", "EXECUTION_ERROR", "IDLE"),  # not in SAFE
            ("ABORT", "EXECUTION_ERROR", "IDLE"),  # nothing to abort
            ("START", "OK", "INIT"),
            ("START", "EXECUTION_ERROR", "INIT"),  # already running
            ("RESUME", "EXECUTION_ERROR", "INIT"),  # not in SAFE
            ("ABORT", "OK", "SAFE"),
            ("ABORT", "EXECUTION_ERROR", "SAFE"),  # already safe
            ("START", "EXECUTION_ERROR", "SAFE"),  # not from SAFE
            ("RESUME", "OK", "INIT"),  # nothing mapped yet: the panorama again
        ]
        moves = b.exe.bus.subscribe(MOTION_REQUEST, "test.moves", depth=16)
        answered = b.exe.commands.dispatched
        for i, (name, status, phase) in enumerate(steps):
            refused = len(b.events("mission.COMMAND_REFUSED"))
            r = b.command(f"mission.{name}")
            assert (r.status.name, _phase(b)) == (status, phase), (i, name, r.message)
            assert b.exe.commands.dispatched == answered + i + 1  # exactly one answer
            assert len(b.events("mission.COMMAND_REFUSED")) == refused + (status != "OK")
            assert b.tlm("mission.state") == (None if phase == "IDLE" else phase)  # published on change
        assert mission.safe.entries == 1 and mission.safe.reason == "aborted by command"
        assert [e.text for e in b.events("mission.SAFE")] == ["SAFE mode: aborted by command"]
        # ABORT stopped the wheels and parked the mast; no other command asked for a move.
        assert [(m.request_id, m.kind) for m in moves.drain()] == [(0, "stop"), (0, "mast")]


def test_goto_longer_than_steer_timeout_completes() -> None:
    """Regression: each segment of a GOTO (turn, drive, turn) gets its own steering time."""
    from hil_sim.bench import LockstepBench

    cfg = load_settings()
    cfg = dataclasses.replace(
        cfg,
        mission=dataclasses.replace(cfg.mission, auto_start=False),
        motion=dataclasses.replace(cfg.motion, steer_timeout_s=2.0),
    )
    with LockstepBench(cfg, None, seed=0, quiet=True, camera=False) as b:
        b.run(20)
        assert b.command("motion.GOTO", x_m=0.5, y_m=0.3, yaw_deg=-20.0, use_yaw=True).status.name == "OK"
        b.run_until(lambda: bool(b.events("motion.MOVE_DONE") or b.events("motion.MOVE_ABORTED")), 600)
        assert b.events("motion.MOVE_DONE") and not b.events("motion.MOVE_ABORTED")
        x, y, yaw = b.rig.rover.pose
        assert abs(x - 0.5) < 0.05 and abs(y - 0.3) < 0.05
