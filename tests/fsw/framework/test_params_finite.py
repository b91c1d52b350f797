"""Config values are finite (issue 12, item 2): NaN, inf and -inf are refused for every numeric key.

The keys are enumerated from the dataclass declarations of every configuration the project
loads (``FswConfig`` for ``config/fsw.toml``, including ``[mavlink]`` and what the ground tools
read; ``HardwareConfig`` for ``config/hil_hardware.toml``; ``ScenarioConfig`` for each
``config/scenarios/*.toml``; the bench's ``[[faults]]`` files), never from a hand list. Each
key is set to a non-finite value in an otherwise valid copy of the shipped file and loaded
through the command-line tool that reads it: exit 2 and exactly one line naming the file and
the key.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import re
import tomllib
import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fsw import cli as fsw_cli
from fsw.framework.params import ConfigError, build, param
from fsw.settings import DEFAULT_CONFIG, FswConfig
from hil_sim import cli as hil_cli
from hil_sim.faults import FaultList
from hil_sim.rig import DEFAULT_HARDWARE, HardwareConfig
from hil_sim.world.config import KINDS, SCENARIO_DIR, ScenarioConfig

Step = str | int  # a table key or an array index
NON_FINITE = (math.nan, math.inf, -math.inf)
FAULTS_BASE = {"faults": [{"kind": "can_drop", "rate": 0.1}]}


def numeric_keys(cls: type, path: tuple[Step, ...] = ()) -> Iterator[tuple[Step, ...]]:
    """Every numeric leaf of the dataclass ``cls``, from its declarations (arrays: element 0)."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        yield from _leaves(hints[f.name], (*path, f.name))


def _leaves(tp: Any, path: tuple[Step, ...]) -> Iterator[tuple[Step, ...]]:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        yield from numeric_keys(tp, path)  # type: ignore[arg-type]
    elif origin in (typing.Union, types.UnionType):
        for alt in args:
            if alt is not type(None):
                yield from _leaves(alt, path)
    elif origin is tuple and args:
        yield from _leaves(args[0], (*path, 0))
    elif origin is dict:
        yield from _leaves(args[1], (*path, "any_key"))
    elif tp in (int, float):
        yield path


def _set(data: dict[str, Any], path: tuple[Step, ...], value: Any) -> None:
    node: Any = data
    for step, nxt in zip(path[:-1], path[1:], strict=True):
        if isinstance(step, int):
            if not node:
                node.append({} if isinstance(nxt, str) else [])
            node = node[step]
        else:
            if step not in node or node[step] is None:
                node[step] = [] if isinstance(nxt, int) else {}
            node = node[step]
    last = path[-1]
    if isinstance(last, int):
        if node:
            node[last] = value
        else:
            node.append(value)
    else:
        node[last] = value


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def _toml_key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def dumps(data: dict[str, Any]) -> str:
    """A minimal TOML writer (one line per top-level key; inline tables), enough for these files."""
    return "".join(f"{_toml_key(k)} = {_toml_value(v)}\n" for k, v in data.items())


def _dotted(path: tuple[Step, ...]) -> str:
    out = ""
    for step in path:
        out += f"[{step}]" if isinstance(step, int) else (f".{step}" if out else str(step))
    return out


# (root, base data, how to run the CLI on a file) for every configuration the project loads
@functools.cache
def _parsed(path: Path) -> dict[str, Any]:
    return tomllib.loads(path.read_text())


def _base(path: Path) -> dict[str, Any]:
    return copy.deepcopy(_parsed(path))


SCENARIOS = sorted(SCENARIO_DIR.glob("*.toml"))
ROOTS: list[tuple[str, type, Any]] = [
    ("fsw", FswConfig, lambda: _base(DEFAULT_CONFIG)),
    ("hardware", HardwareConfig, lambda: _base(DEFAULT_HARDWARE)),
    ("faults", FaultList, lambda: json.loads(json.dumps(FAULTS_BASE))),
    *[(f"scenario:{p.stem}", ScenarioConfig, (lambda p=p: _base(p))) for p in SCENARIOS],
]


def _relevant(root: str, key: tuple[Step, ...]) -> bool:
    """Scenario files: the common tables once (first file), each file's own kind table."""
    if not root.startswith("scenario:"):
        return True
    stem = root.split(":", 1)[1]
    kind = _base(SCENARIO_DIR / f"{stem}.toml")["scenario"]["kind"]
    if key[0] in KINDS:
        return key[0] == kind
    return stem == SCENARIOS[0].stem


CASES = [(name, cls, base, key) for name, cls, base in ROOTS for key in numeric_keys(cls) if _relevant(name, key)]


def _run_cli(root: str, file: Path) -> int:
    if root == "fsw":
        return fsw_cli.main(["dictionary", "--config", str(file)])
    common = ["serve", "--duration", "0.01", "--scenario", "flat"]
    if root == "hardware":
        return hil_cli.main([*common, "--hardware", str(file)])
    if root == "faults":
        return hil_cli.main([*common, "--faults", str(file)])
    return hil_cli.main(["serve", "--duration", "0.01", "--scenario", str(file)])


def test_every_config_root_has_many_numeric_keys() -> None:
    """The enumeration reaches nested tables, arrays of tables and optional tables."""
    keys = {_dotted(k) for _, cls, _ in ROOTS[:1] for k in numeric_keys(cls)}
    assert len(keys) > 100
    assert {"executive.frame_period_s", "executive.groups[0].divisor", "link.give_up_s", "map.cell_m"} <= keys
    assert {"link.rate_bps", "rover.max_speed_mps", "codec.error_bound_wheels", "link.reorder_slack_s"} <= keys


def test_shipped_files_are_valid_and_written_back_identically() -> None:
    """The test's TOML writer round-trips every base file, so a refusal is due to the value alone."""
    for _, cls, base in ROOTS:
        data = base()
        assert tomllib.loads(dumps(data)) == data
        build(cls, data)


def _refused_by_cli(root: str, key: tuple[Step, ...], base: Any, value: float, tmp_path: Path, capsys: Any) -> None:
    data = base()
    _set(data, key, value)
    file = tmp_path / f"{root.replace(':', '_')}.toml"
    file.write_text(dumps(data))
    capsys.readouterr()
    assert _run_cli(root, file) == 2, (root, _dotted(key), value)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"{file}: {_dotted(key)}: " in lines[0], lines[0]


def test_every_numeric_key_refuses_nan_inf_and_minus_inf_in_the_loader() -> None:
    """req(12.2): every key x {nan, inf, -inf}: ``ConfigError`` naming exactly that key, one line."""
    assert len(CASES) > 300
    for _root, cls, base, key in CASES:
        for value in NON_FINITE:
            data = base()
            _set(data, key, value)
            with pytest.raises(ConfigError) as err:
                build(cls, data, source="f.toml")
            assert err.value.key == _dotted(key) and "\n" not in str(err.value), (_dotted(key), value, err.value)


@pytest.mark.slow  # seconds of CPU
def test_every_numeric_key_is_refused_by_its_cli_with_exit_2_and_one_line(tmp_path: Path, capsys: Any) -> None:
    """req(12.2): through the command-line tool that reads the file: exit 2, one line, file and key."""
    for i, (root, _cls, base, key) in enumerate(CASES):
        _refused_by_cli(root, key, base, NON_FINITE[i % 3], tmp_path, capsys)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(CASES), value=st.sampled_from(NON_FINITE))
def test_property_any_key_any_non_finite_value_exit_2(
    case: tuple[str, type, Any, tuple[Step, ...]], value: float, tmp_path: Path, capsys: Any
) -> None:
    """req(12.2): hypothesis draws (key, value) pairs beyond the rotation of the sweep above."""
    root, _cls, base, key = case
    _refused_by_cli(root, key, base, value, tmp_path, capsys)


def test_allow_inf_admits_infinity_only_where_declared() -> None:
    """A key that documents inf (``allow_inf=True``) takes it; NaN is still refused."""

    @dataclasses.dataclass(frozen=True)
    class Limits:
        timeout_s: float = param(1.0, lo=0.0, allow_inf=True, doc="inf: no timeout")
        period_s: float = param(1.0, lo=0.0)

    assert build(Limits, {"timeout_s": math.inf}).timeout_s == math.inf
    for bad in ({"timeout_s": math.nan}, {"period_s": math.inf}, {"period_s": -math.inf}):
        with pytest.raises(ConfigError, match="nan is not a number|must be finite"):
            build(Limits, bad)
