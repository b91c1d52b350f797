"""Campaign specs (issue 16, item 1): validation with one-line errors, deterministic expansion
of scenario families (grids, seeded samples) and fault sets into missions; the CLI's exit 2."""

from __future__ import annotations

import math
import time
from collections import Counter
from pathlib import Path

import pytest

from fsw.framework.params import ConfigError
from fsw.settings import DEFAULT_CONFIG
from hil_sim.cli import main
from hil_sim.lab.campaign.spec import Mission, expand, family_points, load_spec, mission_count, scenario_string

CAMPAIGNS = DEFAULT_CONFIG.parent / "campaigns"
BASE = """
[campaign]
name = "t"
steps = 2
seeds = [0, 1]
methods = ["5", "oracle"]

[[families]]
name = "lab"
scenario = "lab"
grid = { "lab.drop_m" = [0.3, 0.5] }
[families.random]
count = 3
seed = 4
uniform = { "lab.edge_wiggle_m" = [0.0, 0.1] }
choice = { "noise_sigma" = [1.0, 3.0] }

[faults]
mode = "sample"
fraction = 0.5
seed = 2

[[faults.sets]]
name = "bus_off"
faults = [{ kind = "bus_off", start_s = 20.0, duration_s = 2.0 }]
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "spec.toml"
    p.write_text(text)
    return p


def test_expansion_is_deterministic_and_paired(tmp_path: Path) -> None:
    spec = load_spec(write(tmp_path, BASE))
    a, b = expand(spec), expand(load_spec(write(tmp_path, BASE)))
    assert [m.id for m in a] == [m.id for m in b] and [m.key() for m in a] == [m.key() for m in b]
    assert len(a) == 2 * 3 * 2 * 2  # grid x samples x seeds x methods
    assert len({m.id for m in a}) == len(a)
    # every (point, seed) pair has the same faults for both methods
    pairs: dict[tuple[str, int], set[str]] = {}
    for m in a:
        pairs.setdefault((m.scenario, m.seed), set()).add(m.fault_set)
    assert all(len(v) == 1 for v in pairs.values())
    assert {next(iter(v)) for v in pairs.values()} == {"none", "bus_off"}
    assert sum(next(iter(v)) == "bus_off" for v in pairs.values()) == round(0.5 * len(pairs))
    for m in a:
        assert m.scenario.startswith("lab?") and "lab.drop_m=" in m.scenario and "lab.edge_wiggle_m=" in m.scenario
        assert 0.0 <= m.params["lab.edge_wiggle_m"] <= 0.1 and m.params["noise_sigma"] in (1.0, 3.0)
        assert m.faults == () if m.fault_set == "none" else m.faults[0]["kind"] == "bus_off"


def test_cross_mode_adds_the_clean_baseline(tmp_path: Path) -> None:
    spec = load_spec(write(tmp_path, BASE.replace('mode = "sample"', 'mode = "cross"')))
    ms = expand(spec)
    assert len(ms) == 2 * 3 * 2 * 2 * 2
    assert sum(m.fault_set == "none" for m in ms) == len(ms) // 2


def test_scenario_strings_append_to_an_existing_query() -> None:
    assert scenario_string("mars?seed=3", {"mars.k": 0.1}) == "mars?seed=3&mars.k=0.1"
    assert scenario_string("lab", {}) == "lab"
    assert scenario_string("lab", {"b": True, "a": 2}) == "lab?a=2&b=true"


def test_samples_change_with_their_seed_only(tmp_path: Path) -> None:
    s1 = load_spec(write(tmp_path, BASE))
    s2 = load_spec(write(tmp_path, BASE.replace("seed = 4", "seed = 5")))
    assert family_points(s1.families[0]) == family_points(load_spec(write(tmp_path, BASE)).families[0])
    assert family_points(s1.families[0]) != family_points(s2.families[0])


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("steps = 2", "steps = -1", "campaign.steps"),
        ("steps = 2", "stepz = 2", "campaign.stepz"),
        ('methods = ["5", "oracle"]', 'methods = ["6"]', "campaign.methods"),
        ("seeds = [0, 1]", "seeds = [0, -1]", "campaign.seeds"),
        ("[0.0, 0.1]", "[0.0, nan]", "edge_wiggle_m"),
        ("[0.0, 0.1]", "[0.0, inf]", "edge_wiggle_m"),
        ("[0.0, 0.1]", "[0.2, 0.1]", "edge_wiggle_m"),
        ("[0.3, 0.5]", "[0.3, nan]", "lab.drop_m"),
        ("[0.3, 0.5]", "[]", "lab.drop_m"),
        ('"lab.drop_m"', '"lab.no_such_key"', "scenario"),
        ('scenario = "lab"', 'scenario = "atlantis"', "scenario"),
        ("[0.3, 0.5]", "[0.3, -5.0]", "scenario"),
        ('kind = "bus_off"', 'kind = "gremlins"', "kind"),
        ("start_s = 20.0", "start_s = -1.0", "start_s"),
        ("fraction = 0.5", "fraction = 1.5", "faults.fraction"),
        ('name = "bus_off"', 'name = "none"', "faults.sets.name"),
        ('kind = "bus_off"', 'kind = "stuck_task", target = "no_such_task"', "faults.sets[0].faults.target"),
        ('kind = "bus_off"', 'kind = "stuck_task"', "needs a target task"),
        ("seed = 2", 'seed = 2\nunit = "point"', "faults.unit"),
        ("seed = 2", 'seed = 2\ntogether = ["7"]', "faults.together"),
        ('name = "bus_off"', 'name = "bus_off"\njitter_s = -1.0', "jitter_s"),
    ],
)
def test_bad_specs_are_one_line_errors(tmp_path: Path, old: str, new: str, key: str) -> None:
    assert old in BASE
    with pytest.raises(ConfigError) as err:
        load_spec(write(tmp_path, BASE.replace(old, new, 1)))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(str(tmp_path / "spec.toml")) and key in msg


MISSION_UNIT = BASE.replace('methods = ["5", "oracle"]', 'methods = ["1", "3", "5", "oracle"]').replace(
    "seed = 2\n", 'seed = 2\nunit = "mission"\nbalanced = true\n').replace(
    'name = "bus_off"', 'name = "bus_off"\njitter_s = 50.0') + """
[[faults.sets]]
name = "hang"
faults = [{ kind = "stuck_task", target = "nbv", start_s = 10.0, duration_s = 5.0 }]

[[faults.sets]]
name = "radio"
faults = [{ kind = "radio_outage", start_s = 100.0, duration_s = 60.0 }]
"""


def test_mission_unit_keeps_method5_with_its_oracle_and_deals_the_sets_evenly(tmp_path: Path) -> None:
    ms = expand(load_spec(write(tmp_path, MISSION_UNIT)))
    assert ms == expand(load_spec(write(tmp_path, MISSION_UNIT)))  # deterministic
    by_pair: dict[tuple[str, int], dict[str, Mission]] = {}
    for m in ms:
        by_pair.setdefault((m.scenario, m.seed), {})[m.method] = m
    assert len(by_pair) == 12 and all(len(p) == 4 for p in by_pair.values())
    # units: methods 1 and 3 alone, 5 with the oracle: 3 a pair, 36 in all, half of them faulted
    assert all(p["5"].faults == p["oracle"].faults and p["5"].fault_set == p["oracle"].fault_set
               for p in by_pair.values())
    units = [p[k].fault_set for p in by_pair.values() for k in ("1", "3", "5")]
    assert sorted(Counter(units).items()) == [("bus_off", 6), ("hang", 6), ("none", 18), ("radio", 6)]
    assert any(p["1"].fault_set != p["3"].fault_set for p in by_pair.values())  # not paired: drawn per mission
    starts = {m.faults[0]["start_s"] for m in ms if m.fault_set == "bus_off"}
    assert len(starts) > 1 and all(20.0 <= t <= 70.0 for t in starts)  # seeded times in [start, start + jitter]
    assert {m.faults[0]["start_s"] for m in ms if m.fault_set == "hang"} == {10.0}  # no jitter: as written


def test_shipped_campaigns_are_valid() -> None:
    smoke = expand(load_spec(CAMPAIGNS / "smoke.toml"))
    assert len(smoke) == 4
    robust = expand(load_spec(CAMPAIGNS / "default.toml"))
    assert 90 <= len(robust) <= 110
    assert {m.method for m in robust} == {"1", "2", "3", "4", "5", "oracle"}
    faulted = sum(m.fault_set != "none" for m in robust) / len(robust)
    assert faulted == 0.25, faulted  # exactly round(fraction x pairs) pairs, every method of a pair
    assert all(math.isfinite(v) for m in robust for v in m.params.values())
    r100 = expand(load_spec(CAMPAIGNS / "robustness.toml"))
    assert 100 <= len(r100) <= 110 and {m.method for m in r100} == {"1", "2", "3", "4", "5", "oracle"}
    kinds = Counter(f["kind"] for m in r100 for f in m.faults)
    assert set(kinds) == {"can_drop", "bus_off", "motor_fault", "serial_noise", "camera_dropout", "stuck_task",
                          "radio_outage"} and min(kinds.values()) >= 3
    assert 0.2 <= sum(m.fault_set != "none" for m in r100) / len(r100) <= 0.3
    assert all(m.scenario.startswith("terrain?") for m in r100)
    rec = expand(load_spec(CAMPAIGNS / "recovery.toml"))
    assert len(rec) == 18 and len({m.fault_set for m in rec}) == 9


@pytest.mark.parametrize(
    "argv",
    [
        ["campaign", "/nonexistent/spec.toml"],
        ["campaign", str(CAMPAIGNS / "smoke.toml"), "--jobs", "0"],
        ["campaign", str(CAMPAIGNS / "smoke.toml"), "--scheduler", "127.0.0.1"],
    ],
)
def test_cli_bad_input_exits_2_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("safer-hil campaign:") and "\n" not in err


def test_cli_dry_run_lists_the_missions(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", str(CAMPAIGNS / "smoke.toml"), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.strip().endswith("4 missions") and "lab-p000-s0-camera_dropout-m5" in out


def test_mission_count_matches_the_expansion(tmp_path: Path) -> None:
    """req(26.6): the count that guards the size is exactly the number of missions expanded."""
    for spec in (load_spec(write(tmp_path, BASE)), *(load_spec(CAMPAIGNS / f"{n}.toml")
                                                     for n in ("smoke", "default", "recovery"))):
        assert mission_count(spec) == len(expand(spec))


def test_oversized_spec_is_refused_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """req(26.6): 100k seeds x 2 methods x (clean + 1 set) is refused in one line, exit 2, fast;
    100k missions (the limit) still answer a --dry-run. CPU time, not wall time: the machine is shared."""
    seeds = "seeds = [" + ", ".join(map(str, range(100_000))) + "]"
    big = write(tmp_path, (CAMPAIGNS / "smoke.toml").read_text().replace("seeds = [0]", seeds))
    t0 = time.process_time()
    assert main(["campaign", str(big), "--dry-run"]) == 2
    assert time.process_time() - t0 < 10.0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "400,000 missions is more than 100,000" in err
    ok = big.with_name("ok.toml")
    ok.write_text(big.read_text().replace('methods = ["5", "oracle"]', 'methods = ["5"]')
                  .replace('mode = "cross"', 'mode = "sample"'))
    t0 = time.process_time()
    assert main(["campaign", str(ok), "--dry-run"]) == 0
    assert time.process_time() - t0 < 30.0
    assert capsys.readouterr().out.strip().endswith("100000 missions")
