"""Configs that lie are refused (issue 26, item 6): mutations of ``config/fsw.toml``.

Each mutation (a task, section or key deleted, the file truncated, a task moved to 1 Hz, an
empty name, an unknown kind, deep nesting) must be refused by ``load_settings`` with a
``ConfigError`` of one line, and by ``safer-fsw`` with exit code 2, one line and no traceback.
"""

from __future__ import annotations

import random
import re
from collections.abc import Callable
from pathlib import Path

import pytest

from fsw.cli import main
from fsw.framework.params import MAX_DEPTH, ConfigError
from fsw.settings import DEFAULT_CONFIG, load_settings

GOOD = DEFAULT_CONFIG.read_text()
LINES = GOOD.splitlines(keepends=True)
KEY_LINE = re.compile(r"^\s*[A-Za-z_][A-Za-z0-9_]*\s*=\s*(?P<value>.*?)\s*(#.*)?$")


def _complete_key_lines() -> list[int]:
    """Lines holding a whole ``key = value`` (not the start of a multi-line array)."""
    out = []
    for i, ln in enumerate(LINES):
        m = KEY_LINE.match(ln.rstrip("\n"))
        if m and m.group("value").count("[") == m.group("value").count("]"):
            out.append(i)
    return out


def _blocks(header: str) -> list[tuple[int, int]]:
    """(start, end) line ranges of each table whose header line starts with ``header``."""
    starts = [i for i, ln in enumerate(LINES) if ln.startswith(header)]
    heads = [i for i, ln in enumerate(LINES) if ln.startswith("[")]
    return [(s, next((h for h in heads if h > s), len(LINES))) for s in starts]


def _without(a: int, b: int) -> str:
    return "".join(LINES[:a] + LINES[b:])


def _mutations() -> list[tuple[str, str]]:
    muts: list[tuple[str, str]] = []
    for a, b in _blocks("[[executive.tasks]]"):
        name = re.search(r'name = "([^"]*)"', "".join(LINES[a:b]))
        muts.append((f"delete task {name.group(1) if name else a}", _without(a, b)))
        block = "".join(LINES[a:b])
        if 'group = "fast"' in block:  # the 10 Hz tasks moved to the 1 Hz group
            muts.append((f"move task {name.group(1) if name else a} to 1 Hz",
                         "".join(LINES[:a]) + block.replace('group = "fast"', 'group = "slow"') + "".join(LINES[b:])))
    for a, b in _blocks("["):
        if not LINES[a].startswith("[["):
            muts.append((f"delete section {LINES[a].split()[0]}", _without(a, b)))
    rng = random.Random(26)
    keys = _complete_key_lines()
    for i in rng.sample(keys, 80):
        muts.append((f"delete key line {i + 1}: {LINES[i].split('=')[0].strip()}", _without(i, i + 1)))
    meaningful = [i for i, ln in enumerate(LINES) if ln.strip() and not ln.lstrip().startswith("#")]
    for cut in sorted(rng.sample(range(1, meaningful[-1] + 1), 40)):
        muts.append((f"truncate after line {cut}", "".join(LINES[:cut])))
    for m in re.finditer(r'name = "([^"]*)"', GOOD):
        muts.append((f"empty name {m.group(1)}", GOOD[: m.start()] + 'name = ""' + GOOD[m.end():]))
    muts.append(("frame period 1 s", GOOD.replace("frame_period_s = 0.1 ", "frame_period_s = 1.0 ", 1)))
    muts.append(("unknown kind", GOOD.replace('kind = "nbv"', 'kind = "nbv2"', 1)))
    muts.append(("disabled mission", GOOD.replace('kind = "mission"\n', 'kind = "mission"\nenabled = false\n', 1)))
    muts.append(("deep array", GOOD + "\n[extra]\nx = " + "[" * 5000 + "]" * 5000 + "\n"))
    muts.append(("deep tables", GOOD + "\n[" + ".".join(f"t{i}" for i in range(MAX_DEPTH + 5)) + "]\nx = 1\n"))
    muts.append(("deep inline", GOOD + "\nextra = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n"))
    return muts


MUTATIONS = _mutations()


def test_the_shipped_file_is_accepted() -> None:
    """The property below is not vacuous: the unmutated file loads."""
    assert load_settings().executive.flight


def test_every_lying_mutation_is_refused_in_one_line(tmp_path: Path) -> None:
    """req(26.6): every mutation raises ConfigError of one line naming the file."""
    p = tmp_path / "fsw.toml"
    accepted = []
    for what, text in MUTATIONS:
        assert text != GOOD, what
        p.write_text(text)
        try:
            load_settings(p)
        except ConfigError as err:
            assert "\n" not in str(err) and str(p) in str(err), (what, str(err))
        else:
            accepted.append(what)
    assert len(MUTATIONS) > 150
    assert accepted == []


@pytest.mark.parametrize(
    ("what", "mutate", "reason"),
    [
        ("a task deleted", lambda s: s.replace('kind = "imu_device"', 'kind = "noop"'), "'imu_device'"),
        ("1 Hz motion", lambda s: s.replace('name = "motion"               # wheel and mast moves, odometry '
                                            '(after the device components)\nkind = "motion"\ngroup = "fast"',
                                            'name = "motion"\nkind = "motion"\ngroup = "slow"'), "design range"),
        ("empty name", lambda s: s.replace('name = "nbv"', 'name = ""'), "task name ''"),
        ("unknown kind", lambda s: s.replace('kind = "nbv"', 'kind = "nbv2"'), "unknown task kind 'nbv2'"),
        ("deep nesting", lambda s: s + "\nx = " + "[" * 5000 + "]" * 5000 + "\n", "nested deeper"),
        ("missing key", lambda s: s.replace("keep = 3 ", "# keep = 3 "), "checkpoint.keep: missing key"),
        ("truncated", lambda s: s[: s.index("[checkpoint]")], "checkpoint: missing table"),
    ],
)
def test_cli_refuses_with_exit_2_and_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], what: str, mutate: Callable[[str], str], reason: str
) -> None:
    """req(26.6): ``safer-fsw run`` on a lying config: exit 2, one stderr line, no traceback."""
    p = tmp_path / "fsw.toml"
    text = mutate(GOOD)
    assert text != GOOD, what
    p.write_text(text)
    assert main(["run", "--config", str(p), "--duration", "0.1"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and reason in err[0] and "Traceback" not in err[0], (what, err)
