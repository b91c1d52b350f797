"""Issue 2, item 3: bad configuration files give one clear line and exit code 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fsw.cli import main
from fsw.framework.params import ConfigError
from fsw.settings import DEFAULT_CONFIG, load_settings

GOOD = DEFAULT_CONFIG.read_text()


def test_shipped_config_loads() -> None:
    cfg = load_settings()
    assert cfg.executive.frame_period_s == pytest.approx(0.1)
    assert cfg.camera.focal_px > 0


@pytest.mark.parametrize(
    ("mutate", "key", "reason"),
    [
        (  # a key with a default, left out of a flight file: refused (the file is the whole record)
            lambda s: s.replace("frame_period_s = 0.1", "# (default)", 1),
            "executive.frame_period_s",
            "missing key",
        ),
        (  # ... in a bench file (flight = false) it takes its documented default
            lambda s: s.replace("frame_period_s = 0.1", "# (default)", 1).replace("flight = true", "flight = false"),
            "",
            "",
        ),
        (
            lambda s: s.replace(
                'name = "health"\nkind = "health"\ngroup = "slow"\n', 'name = "health"\nkind = "health"\n'
            ),
            "executive.tasks[0].group",
            "missing required key",
        ),
        (
            lambda s: s.replace("frame_period_s = 0.1", 'frame_period_s = "fast"'),
            "executive.frame_period_s",
            "expected a number",
        ),
        (
            lambda s: s.replace("frame_period_s = 0.1", "frame_period_s = -1.0"),
            "executive.frame_period_s",
            "below the minimum",
        ),
        (lambda s: s.replace("[camera]\n", "[camera]\nfocal_mm = 8\n"), "camera.focal_mm", "unknown key"),
        (
            lambda s: s.replace('group = "slow"\nbudget_ms = 1.0', 'group = "nope"\nbudget_ms = 1.0'),
            "executive",
            "unknown rate group",
        ),
        (lambda s: s + "\n[[[broken", "", "not valid TOML"),
        (lambda s: s.replace("min_range_m = 0.8", "min_range_m = 9.0"), "camera", "min_range_m must be below"),
    ],
)
def test_bad_config_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], mutate, key: str, reason: str
) -> None:
    """Each bad-config case: exit code 2 and a single line naming file, key and reason."""
    p = tmp_path / "fsw.toml"
    p.write_text(mutate(GOOD))
    rc = main(["dictionary", "--config", str(p)])
    out = capsys.readouterr()
    if not reason:
        assert rc == 0
        return
    assert rc == 2
    lines = [ln for ln in out.err.splitlines() if ln.strip()]
    assert len(lines) == 1, out.err
    assert str(p) in lines[0] and reason in lines[0]
    if key:
        assert key in lines[0]
    assert "Traceback" not in out.err


def test_missing_and_unreadable_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--config", str(tmp_path / "nope.toml")]) == 2
    assert "file not found" in capsys.readouterr().err
    assert main(["run", "--config", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    bad = tmp_path / "bin.toml"
    bad.write_bytes(b"\xff\xfe\x00garbage")
    assert main(["run", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and str(bad) in err


def test_config_error_message_format() -> None:
    err = ConfigError("a.toml", "x.y", "because")
    assert str(err) == "a.toml: x.y: because"


def test_usage_error_exit_2() -> None:
    r = subprocess.run([sys.executable, "-m", "fsw.cli", "frobnicate"], capture_output=True, text=True)
    assert r.returncode == 2 and "usage" in r.stderr


def test_dictionary_generated_from_declarations(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 2, item 8: one dictionary from the declarations, unique ids and opcodes."""
    import json

    assert main(["dictionary"]) == 0
    d = json.loads(capsys.readouterr().out)
    names = [c["name"] for c in d["commands"]]
    assert "health.NOOP" in names and "health.RESET_COUNTERS" in names and "exec.SET_TASK_ENABLED" in names
    assert len({c["opcode"] for c in d["commands"]}) == len(d["commands"])
    assert len({e["id"] for e in d["events"]}) == len(d["events"])
    assert {e["severity"] for e in d["events"]} >= {"FATAL", "WARNING_HI", "WARNING_LO", "ACTIVITY_HI"}
