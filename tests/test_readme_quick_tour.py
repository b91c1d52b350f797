"""Issue 29, item 5: the README's quick tour runs as written.

Every ``.venv/bin/...`` command of the quick tour is found (its subcommand answers ``--help``);
the cheap ones run in full in a scratch folder with a scratch home: the dictionary, the render
of a stereo pair and ``keygen --out ~/...`` (whose folder does not exist yet)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
CHEAP = ("safer-fsw dictionary", "safer-ground keygen", "safer-hil render")


def tour_commands() -> list[list[str]]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick tour\n```\n(.*?)```", text, re.S)
    assert block, "README has no quick tour block"
    cmds = []
    for line in block.group(1).splitlines():
        line = line.split(" #", 1)[0].split("|", 1)[0]
        for part in line.split("&&"):
            argv = shlex.split(part)
            if argv and argv[0].startswith(".venv/bin/"):
                cmds.append(argv)
    return cmds


def _help(exe: Path, sub: list[str]) -> tuple[int, str]:
    """The console script's entry point called with ``SUB --help`` in this process (exit code, output).

    Each ``safer-*`` script is the entry point of its name in the installed distribution
    (``[project.scripts]``); running it in a process of its own would import the program once
    more per command. That the installed scripts start as processes is checked by
    test_ground_cli.py (``safer-ground --help``) and the real-time team tests (``safer-hil``,
    ``safer-fsw``)."""
    import contextlib
    import io
    from importlib.metadata import entry_points

    (ep,) = entry_points(group="console_scripts", name=exe.name)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            code = ep.load()([*sub, "--help"])
        except SystemExit as exc:
            code = exc.code
    return (code if isinstance(code, int) else 1 if code else 0), out.getvalue()


def test_the_tour_names_real_commands() -> None:
    cmds = tour_commands()
    assert len(cmds) >= 8
    helped: set[tuple[str, ...]] = set()
    for argv in cmds:
        exe = BIN / Path(argv[0]).name
        assert exe.exists(), argv[0]
        sub = [a for a in argv[1:2] if not a.startswith("-")]
        if (key := (exe.name, *sub)) in helped:
            continue  # the same command's --help (the tour runs `safer-hil run` four ways)
        helped.add(key)
        code, text = _help(exe, sub)
        assert code == 0 and "usage:" in text, (argv, text[-500:])
    assert len(helped) >= 6


@pytest.mark.slow
def test_the_cheap_tour_commands_run_as_written(tmp_path: Path) -> None:
    env = {**os.environ, "HOME": str(tmp_path / "home")}
    ran = 0
    for argv in tour_commands():
        name = f"{Path(argv[0]).name} {argv[1] if len(argv) > 1 else ''}"
        if not name.startswith(CHEAP):
            continue
        args = [os.path.expanduser(a.replace("~", str(tmp_path / "home"), 1)) if a.startswith("~") else a
                for a in argv[1:]]
        out = subprocess.run([str(BIN / Path(argv[0]).name), *args], capture_output=True, text=True,
                             timeout=300, cwd=tmp_path, env=env)
        assert out.returncode == 0, (argv, out.stderr[-800:])
        ran += 1
    assert ran == len(CHEAP)
    assert (tmp_path / "home" / ".safer" / "key").stat().st_mode & 0o077 == 0
