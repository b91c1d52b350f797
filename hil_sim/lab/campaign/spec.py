"""The campaign spec (``SPEC.toml``) and its expansion into missions.

A campaign declares scenario *families*: a base scenario string the bench accepts (``lab``,
``cliff``, ``mars?seed=3``, ``file:PATH``, any later family such as ``terrain?...``) and the
scenario parameters to vary, as a grid (every combination of the listed values) and/or seeded
random samples (``uniform`` ranges, ``choice`` lists). Each parameter point becomes a scenario
query string ``base?key=value&...`` which the scenario loader validates like any override.
Every point runs for every seed and method; fault sets (rows of :class:`hil_sim.faults.FaultSpec`
at given bench times) are either crossed with every point (``mode = "cross"``, plus the clean
baseline) or given to a seeded ``fraction`` of the (point, seed) pairs (``mode = "sample"``; all
methods of a pair get the same faults, so Method 5 and the oracle stay paired).

The spec is validated like every other config (``fsw.framework.params``): a bad key, type,
range, NaN or infinity, unknown method or fault, or a scenario string the loader refuses is a
:class:`ConfigError` naming ``FILE: KEY: REASON``. The expansion is deterministic: the same
spec gives the same missions, ids and order. The number of missions is counted from the spec
(:func:`mission_count`, no expansion) and a spec of more than ``MAX_MISSIONS`` is refused
before any scenario is checked or mission built, so even a spec of millions answers at once.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fsw.framework.params import ConfigError, build, load_toml, param
from hil_sim.faults import FaultSpec

METHODS = ("1", "2", "3", "4", "5", "oracle")
MAX_MISSIONS = 100_000


@dataclass(frozen=True)
class CampaignSection:
    name: str = param(doc="campaign name (report title)")
    steps: int = param(20, lo=0, hi=1000, doc="imaging steps after the panorama")
    seeds: tuple[int, ...] = param((0,), lo=0, hi=2**31 - 1, doc="mission seeds (world, hardware, radio)")
    methods: tuple[str, ...] = param(("5",), choices=METHODS, doc="mapping methods (docs/algorithm.md §7)")
    timeout_s: float = param(1800.0, lo=1.0, hi=1e6, units="s", doc="wall-clock limit of one mission (killed)")
    max_sim_s: float = param(0.0, lo=0.0, hi=1e6, units="s", doc="bench-time limit (0: the runner's default)")
    safe_recover_s: float = param(30.0, lo=0.0, hi=1e5, units="s", doc="SAFE resumes after this (0: ends)")
    transmit: bool = param(False, doc="send the map to the Cliff-bot at the end")
    config: str = param("", doc="flight configuration (empty: config/fsw.toml)")


@dataclass(frozen=True)
class RandomSection:
    count: int = param(0, lo=0, hi=MAX_MISSIONS, doc="samples drawn")
    seed: int = param(0, lo=0, hi=2**31 - 1, doc="seed of the draws")
    uniform: dict[str, tuple[float, float]] = field(default_factory=dict)  # key -> [lo, hi]
    integers: dict[str, tuple[int, int]] = field(default_factory=dict)  # key -> [lo, hi] inclusive
    choice: dict[str, tuple[Any, ...]] = field(default_factory=dict)  # key -> values


@dataclass(frozen=True)
class Family:
    name: str = param(doc="family name (mission ids, report)")
    scenario: str = param(doc="base scenario string the bench accepts")
    grid: dict[str, tuple[Any, ...]] = field(default_factory=dict)  # key -> values
    random: RandomSection = field(default_factory=RandomSection)


@dataclass(frozen=True)
class FaultSet:
    name: str = param(doc="fault set name (mission ids, report)")
    faults: tuple[FaultSpec, ...] = param(doc="[[...faults]] rows of hil_sim.faults.FaultSpec")
    jitter_s: float = param(0.0, lo=0.0, hi=1e5, units="s",
                            doc="each (point, seed) pair's faults start later by a seeded draw in [0, jitter_s]")


@dataclass(frozen=True)
class FaultPlan:
    mode: str = param("cross", choices=("cross", "sample"), doc="cross: every set and none; sample: a fraction")
    fraction: float = param(0.25, lo=0.0, hi=1.0, doc="sample: fraction of (point, seed) pairs with faults")
    seed: int = param(0, lo=0, hi=2**31 - 1, doc="sample: seed of the draws")
    unit: str = param("pair", choices=("pair", "mission"),
                      doc="sample: what gets one set: a (point, seed) pair's missions alike, or each mission")
    together: tuple[str, ...] = param(("5", "oracle"), choices=METHODS,
                                      doc="unit mission: these methods of a pair share one draw (stay paired)")
    balanced: bool = param(False, doc="sample: deal the sets in turn over the chosen units (each equally often)")
    sets: tuple[FaultSet, ...] = ()


@dataclass(frozen=True)
class CampaignSpec:
    campaign: CampaignSection
    families: tuple[Family, ...] = param(doc="[[families]]")
    faults: FaultPlan = field(default_factory=FaultPlan)


@dataclass(frozen=True)
class Mission:
    """One mission of a campaign: everything its result depends on."""

    id: str
    family: str
    params: dict[str, Any]
    scenario: str
    method: str
    seed: int
    steps: int
    fault_set: str
    faults: tuple[dict[str, Any], ...]
    timeout_s: float
    max_sim_s: float
    safe_recover_s: float
    transmit: bool
    config: str

    def key(self) -> str:
        """Hash of the mission's inputs (a stored result is reused only for the same inputs)."""
        blob = json.dumps({k: v for k, v in asdict(self).items() if k != "timeout_s"}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def load_spec(path: str | Path) -> CampaignSpec:
    """Read and validate ``SPEC.toml``; :class:`ConfigError` (one line) on anything wrong."""
    src = str(path)
    spec = build(CampaignSpec, load_toml(path), source=src)
    names = [f.name for f in spec.families]
    if len(set(names)) != len(names):
        raise ConfigError(src, "families.name", f"duplicate family names {names}")
    if not spec.families:
        raise ConfigError(src, "families", "at least one [[families]] table is needed")
    set_names = [s.name for s in spec.faults.sets]
    if len(set(set_names)) != len(set_names) or "none" in set_names:
        raise ConfigError(src, "faults.sets.name", "fault set names must be unique and not 'none'")
    n = mission_count(spec)
    if n > MAX_MISSIONS:
        raise ConfigError(src, "families", f"{n:,} missions is more than {MAX_MISSIONS:,}")
    for i, fam in enumerate(spec.families):
        key = f"families[{i}]"
        for k, (lo, hi) in fam.random.uniform.items():
            if not lo <= hi:
                raise ConfigError(src, f"{key}.random.uniform.{k}", f"empty range [{lo}, {hi}]")
        for k, (ilo, ihi) in fam.random.integers.items():
            if not ilo <= ihi:
                raise ConfigError(src, f"{key}.random.integers.{k}", f"empty range [{ilo}, {ihi}]")
        for k, vals in (*fam.grid.items(), *fam.random.choice.items()):
            if not vals:
                raise ConfigError(src, f"{key}.{k}", "empty list of values")
            for v in vals:
                if not isinstance(v, (str, int, float, bool)):
                    raise ConfigError(src, f"{key}.{k}", f"values must be strings, numbers or booleans, got {v!r}")
        _check_scenarios(src, key, fam)
    _check_fault_targets(src, spec)
    return spec


def mission_count(spec: CampaignSpec) -> int:
    """How many missions :func:`expand` makes, counted without making them."""
    points = 0
    for fam in spec.families:
        grid = math.prod(len(v) for v in fam.grid.values())
        points += grid * (fam.random.count or 1)
    sets = 1 + len(spec.faults.sets) if spec.faults.mode == "cross" else 1
    return points * len(spec.campaign.seeds) * sets * len(spec.campaign.methods)


def _check_scenarios(src: str, key: str, fam: Family) -> None:
    """Every scenario string of the family must be one the bench accepts (cheap: config only)."""
    from hil_sim.world.config import load_scenario_config

    for point in family_points(fam):
        scen = scenario_string(fam.scenario, point)
        try:
            load_scenario_config(scen)
        except ValueError as exc:
            raise ConfigError(src, f"{key}.scenario", f"{scen!r}: {exc}") from None


def _check_fault_targets(src: str, spec: CampaignSpec) -> None:
    """A ``stuck_task`` fault must name a task of the flight configuration's schedule."""
    from fsw.settings import DEFAULT_CONFIG, load_settings

    targets = {(i, f.target) for i, s in enumerate(spec.faults.sets) for f in s.faults if f.kind == "stuck_task"}
    if not targets:
        return
    tasks = {t.name for t in load_settings(spec.campaign.config or DEFAULT_CONFIG).executive.tasks}
    for i, name in sorted(targets):
        if name not in tasks:
            raise ConfigError(src, f"faults.sets[{i}].faults.target",
                              f"stuck_task target {name!r} is not a flight task ({', '.join(sorted(tasks))})")


def family_points(fam: Family) -> list[dict[str, Any]]:
    """The family's parameter points: grid combinations x random samples (either may be absent)."""
    keys = sorted(fam.grid)
    grid = [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(fam.grid[k] for k in keys))]
    r = fam.random
    if r.count == 0:
        return grid
    rng = np.random.default_rng(r.seed)
    samples = []
    for _ in range(r.count):
        s: dict[str, Any] = {}
        for k in sorted(r.uniform):
            lo, hi = r.uniform[k]
            s[k] = float(f"{rng.uniform(lo, hi):.4g}")
        for k in sorted(r.integers):
            ilo, ihi = r.integers[k]
            s[k] = int(rng.integers(ilo, ihi + 1))
        for k in sorted(r.choice):
            s[k] = r.choice[k][int(rng.integers(0, len(r.choice[k])))]
        samples.append(s)
    return [{**g, **s} for g in grid for s in samples]


def scenario_string(base: str, point: dict[str, Any]) -> str:
    """``base?key=value&...`` (appended with ``&`` when the base already has a query)."""
    if not point:
        return base
    query = "&".join(f"{k}={_fmt(v)}" for k, v in sorted(point.items()))
    return f"{base}{'&' if '?' in base else '?'}{query}"


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def expand(spec: CampaignSpec) -> list[Mission]:
    """All missions of the campaign, in a fixed order that interleaves the families: seed, point
    index, family, faults, method (so a campaign stopped part-way has sampled every family, and
    the methods of a point stay together)."""
    from fsw.settings import DEFAULT_CONFIG

    c = spec.campaign
    plan = spec.faults
    points = [(jf, fam, ip, point) for jf, fam in enumerate(spec.families)
              for ip, point in enumerate(family_points(fam))]
    units = _units(plan, c.methods, len(points) * len(c.seeds))
    sampled = _sample_faults(plan, len(units))
    drawn = {(u[0], m): (fs, k) for k, (u, fs) in enumerate(zip(units, sampled, strict=True)) for m in u[1]}
    out: list[tuple[tuple[int, ...], Mission]] = []
    pair = -1
    for jf, fam, ip, point in points:
        scen = scenario_string(fam.scenario, point)
        for iseed, seed in enumerate(c.seeds):
            pair += 1
            sets: list[FaultSet | None] = [None, *plan.sets] if plan.mode == "cross" else [None]
            for jset, fs0 in enumerate(sets):
                for jm, m in enumerate(c.methods):
                    fs, unit = (fs0, pair) if plan.mode == "cross" else drawn[(pair, m)]
                    fname = fs.name if fs is not None else "none"
                    order = (iseed, ip, jf, jset, jm)
                    out.append((order, Mission(
                            id=f"{fam.name}-p{ip:03d}-s{seed}-{fname}-m{m}",
                            family=fam.name,
                            params=dict(point),
                            scenario=scen,
                            method=m,
                            seed=seed,
                            steps=c.steps,
                            fault_set=fname,
                            faults=_timed_faults(plan, fs, unit, jset),
                            timeout_s=c.timeout_s,
                            max_sim_s=c.max_sim_s,
                            safe_recover_s=c.safe_recover_s,
                            transmit=c.transmit,
                            config=c.config or str(DEFAULT_CONFIG),
                        )))
    return [m for _, m in sorted(out, key=lambda om: om[0])]


def _units(plan: FaultPlan, methods: tuple[str, ...], pairs: int) -> list[tuple[int, tuple[str, ...]]]:
    """The units the ``sample`` mode draws for: (pair index, the methods that share the draw)."""
    if plan.unit == "pair":
        return [(i, methods) for i in range(pairs)]
    together = tuple(m for m in methods if m in plan.together)
    groups = [(m,) for m in methods if m not in together] + ([together] if together else [])
    return [(i, g) for i in range(pairs) for g in groups]


def _timed_faults(plan: FaultPlan, fs: FaultSet | None, unit: int, jset: int) -> tuple[dict[str, Any], ...]:
    """The set's fault rows for one sampling unit (``cross``: one pair): all shifted by one
    seeded draw in ``[0, jitter_s]`` (the same for every method of the unit, so they stay paired)."""
    if fs is None:
        return ()
    shift = 0.0
    if fs.jitter_s > 0:
        shift = float(f"{np.random.default_rng([plan.seed, unit, jset]).uniform(0.0, fs.jitter_s):.4g}")
    return tuple({**asdict(f), "start_s": round(f.start_s + shift, 3)} for f in fs.faults)


def _sample_faults(plan: FaultPlan, units: int) -> list[FaultSet | None]:
    """``sample`` mode: exactly ``round(fraction * units)`` of the units, chosen with the plan's
    seed, get a fault set (drawn uniformly, or with ``balanced`` dealt in turn in a seeded
    order, so every set comes round(n / sets) times); the rest none."""
    out: list[FaultSet | None] = [None] * units
    if plan.mode != "sample" or not plan.sets:
        return out
    rng = np.random.default_rng(plan.seed)
    chosen = rng.choice(units, size=int(round(plan.fraction * units)), replace=False)
    deal = rng.permutation(len(chosen)) if plan.balanced else None
    for j, i in enumerate(sorted(int(k) for k in chosen)):
        if deal is not None:
            out[i] = plan.sets[int(deal[j]) % len(plan.sets)]
        else:
            out[i] = plan.sets[int(rng.integers(0, len(plan.sets)))]
    return out
