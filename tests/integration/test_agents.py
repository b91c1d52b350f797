"""Agents as topologies (docs/architecture.md, "Agents"): a second, small agent kind built from
a configuration file and stepped beside the RECON-bot in one lockstep bench, on one clock.

The ``probe`` agent has two trivial tasks (``tests/support/agent_tasks.py``) in two rate groups
at a frame period twice the RECON-bot's, and MAVLink system id 2. It shares nothing with the
RECON-bot but the clock.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from agent_tasks import BeaconTask, ListenerTask

from fsw import registry
from fsw.cli import main as fsw_main
from fsw.executive.executive import Executive
from fsw.executive.topology import agent_topology, components
from fsw.framework.agent import AgentTopology
from fsw.framework.params import ConfigError
from fsw.settings import FswConfig, load_settings

PROBE = AgentTopology(
    kind="probe",
    doc="a second agent for the tests: a beacon and a listener",
    task_kinds={"beacon": "agent_tasks:BeaconTask", "listener": "agent_tasks:ListenerTask",
                "health": registry.KINDS["health"]},
    sections=frozenset({"mavlink"}),
    required_tasks=("beacon",),
)

PROBE_TOML = """
[agent]
name = "probe-1"
kind = "probe"

[executive]
flight = false
frame_period_s = 0.2
groups = [{name = "fast", divisor = 1}, {name = "slow", divisor = 5, offset = 2}]
tasks = [
  {name = "beacon", kind = "beacon", group = "fast", budget_ms = 50.0},
  {name = "listener", kind = "listener", group = "slow", budget_ms = 50.0},
]

[mavlink]
system_id = 2
"""


@pytest.fixture
def probe_toml(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.setitem(registry.AGENTS, PROBE.kind, PROBE)
    path = tmp_path / "probe.toml"
    path.write_text(PROBE_TOML, encoding="utf-8")
    yield path


def recon_cfg() -> FswConfig:
    cfg = load_settings()
    return dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, auto_start=False))


def test_the_config_picks_the_topology(probe_toml: Path) -> None:
    cfg = load_settings(probe_toml)
    assert cfg.agent.name == "probe-1" and agent_topology(cfg) is PROBE and cfg.mavlink.system_id == 2
    assert [(c.name, c.cls) for c in components(cfg)][-2:] == [("beacon", BeaconTask), ("listener", ListenerTask)]
    assert agent_topology(load_settings()) is registry.RECON


def test_safer_fsw_builds_the_agent_of_its_config(probe_toml: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`safer-fsw dictionary --config` (and `run`, which builds the same components) take the
    topology from the file: the probe's dictionary has its tasks and none of the RECON-bot's."""
    assert fsw_main(["dictionary", "--config", str(probe_toml)]) == 0
    names = {c["name"] for c in json.loads(capsys.readouterr().out)["channels"]}
    assert {"beacon.beats", "listener.heard"} <= names and not any(n.startswith("mission.") for n in names)


@pytest.mark.parametrize(("text", "key"), [
    (PROBE_TOML.replace('kind = "probe"', 'kind = "rover9"'), "agent.kind"),
    (PROBE_TOML + "\n[stereo]\nnum_disparities_px = 64\n", "agent"),  # a section the probe does not read
    (PROBE_TOML.replace('kind = "listener"', 'kind = "mission"'), "executive.tasks"),  # not a probe task
    (PROBE_TOML.replace('kind = "beacon"', 'kind = "listener"'), "executive.tasks"),  # its beacon missing
    (PROBE_TOML.replace('name = "probe-1"', 'name = "probe 1"'), "agent"),
])
def test_a_config_that_does_not_fit_its_agent_is_refused(probe_toml: Path, text: str, key: str) -> None:
    probe_toml.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_settings(probe_toml)
    assert err.value.key == key and "\n" not in str(err.value)


def _trace(exe: Executive) -> list[tuple[float, str, str]]:
    """The agent's events, all of them: in lockstep even the timing events (OVERRUN, SLIP,
    JOB_DONE) are measured on the stepped clock, so the same every time."""
    return [(e.time_s, e.name, e.text) for e in exe.events.history]


Trace = list[tuple[float, str, str]]


def _team_run(probe_path: Path | None, frames: int) -> tuple[Trace, Trace, list[tuple[int, int, float]]]:
    """The RECON-bot (and the probe, if given) for ``frames`` RECON-bot frames: the two event
    traces and the beats the listener heard (number, probe frame, clock time)."""
    from hil_sim.bench import LockstepBench

    with LockstepBench(recon_cfg(), None, seed=0, quiet=True, camera=False) as b:
        probe = b.add_agent(load_settings(probe_path)) if probe_path is not None else None
        b.run(2)
        b.command("mission.START")  # the RECON-bot starts its panorama (no world: it waits for pairs)
        b.run(frames - 2)
        assert b.exe.frame == frames and b.clock.now() == pytest.approx((frames - 1) * 0.1)
        if probe is None:
            return _trace(b.exe), [], []
        assert b.agent("probe-1") is probe and probe.clock is b.clock
        listener, beacon = probe.tasks["listener"], probe.tasks["beacon"]
        assert isinstance(listener, ListenerTask) and isinstance(beacon, BeaconTask)
        assert beacon.beats >= len(listener.heard) > 0
        return _trace(b.exe), _trace(probe), list(listener.heard)


@pytest.mark.slow
def test_a_second_agent_runs_beside_the_recon_bot_on_one_clock(probe_toml: Path) -> None:
    recon, probe, heard = _team_run(probe_toml, 60)
    # 60 RECON-bot frames (0.0 .. 5.9 s at 0.1 s) and the probe's frames at 0.2 s in that time: 0.0 .. 5.8 s
    assert [k for k, _, _ in heard] == list(range(1, len(heard) + 1)) and len(heard) >= 25
    assert all(abs(t / 0.2 - round(t / 0.2)) < 1e-9 and t == pytest.approx(0.2 * f) for _, f, t in heard)
    assert any(name == "listener.HEARD" for _, name, _ in probe)
    assert not any(name.startswith("mission.") for _, name, _ in probe)  # nothing shared but the clock
    assert any(name == "mission.STATE" for _, name, _ in recon)
    # the RECON-bot does exactly what it does alone: the probe beside it changes nothing of it
    alone, _, _ = _team_run(None, 60)
    assert recon == alone


@pytest.mark.slow
def test_the_team_is_deterministic(probe_toml: Path) -> None:
    assert _team_run(probe_toml, 40) == _team_run(probe_toml, 40)


def test_agents_of_one_bench_have_distinct_names_and_system_ids(probe_toml: Path) -> None:
    from hil_sim.bench import LockstepBench

    probe = load_settings(probe_toml)
    with LockstepBench(recon_cfg(), None, seed=0, quiet=True, camera=False) as b:
        b.add_agent(probe)
        with pytest.raises(ValueError, match="named 'probe-1'"):
            b.add_agent(probe)
        other = dataclasses.replace(probe, agent=dataclasses.replace(probe.agent, name="probe-2"))
        with pytest.raises(ValueError, match="system id 2"):
            b.add_agent(other)
