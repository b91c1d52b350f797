"""Issue 29, item 5: Ctrl-C on a mission prints the command that continues it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hil_sim import cli
from hil_sim.commands import run as run_cmd


def _interrupt_after_manifest(args: Any) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "run.json").write_text("{}")
    raise KeyboardInterrupt


def test_ctrl_c_prints_the_resume_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(run_cmd, "run", _interrupt_after_manifest)
    out = tmp_path / "my run"
    assert cli.main(["run", "--out", str(out)]) == 130
    err = capsys.readouterr().err.strip()
    assert err == f"interrupted; continue it with: safer-hil run --resume '{out}'"


def test_ctrl_c_before_anything_was_saved_says_only_interrupted(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def early(args: Any) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(run_cmd, "run", early)
    assert cli.main(["run", "--out", str(tmp_path / "none")]) == 130
    assert capsys.readouterr().err.strip() == "interrupted"


def test_make_demo_first_lines_tell_what_happens(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 29, item 5: the demo's first lines say what runs and where the results go, before any
    event line (KEY_NONE is explained, not the first thing a newcomer reads)."""
    seen: list[Any] = []
    monkeypatch.setattr(run_cmd, "run", lambda ns: seen.append(ns) or 0)
    assert cli.main(["demo", "--steps", "3", "--out", str(tmp_path / "d")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("safer-hil demo: ") and "simulated rover" in lines[0]
    assert any("KEY_NONE" in ln for ln in lines[:5]) and any("summary.json" in ln for ln in lines[:5])
    assert seen and seen[0].steps == 3 and seen[0].fresh


def test_no_option_says_its_default_twice() -> None:
    """Issue 29, item 5: "(default: ...)" is added only where the help does not already say it."""
    import argparse
    import re

    def walk(p: argparse.ArgumentParser, name: str) -> list[str]:
        bad = [f"{name}: {' '.join(para.split())[:80]}" for para in re.split(r"\n(?=  -)", p.format_help())
               if len(re.findall(r"default(?!\.toml)", para.lower())) >= 2 and "(default:" in para]
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for n, sp in a.choices.items():
                    bad += walk(sp, f"{name} {n}")
        return bad

    assert walk(cli.build_parser(), "safer-hil") == []
