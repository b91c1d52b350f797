"""Result files: what an experiment command measured, written where the manuals link to it.

Every ``safer-hil experiment *`` command ends with :func:`write_results`, which writes
``docs/results/<experiment>.md``: the date, the commit the code was at (``git rev-parse``,
marked ``-dirty`` when its code or config had uncommitted changes), the exact command line, the command's own
table and its figures (copied beside the file). Rerunning the command regenerates the file;
nobody edits it by hand, and the manuals carry no measured figures of their own.

The directory is ``docs/results`` of the checkout the bench runs from, or ``$SAFER_RESULTS_DIR``
when set (the test suite points it at a temporary directory). When neither exists (an
installed package, no checkout) nothing is written and the command says so on stderr.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
ENV = "SAFER_RESULTS_DIR"
CODE = ("fsw", "hil_sim", "ground", "config", "pyproject.toml", "constraints.txt")


def results_dir() -> Path | None:
    """Where result files go: ``$SAFER_RESULTS_DIR``, else ``docs/results`` of this checkout."""
    env = os.environ.get(ENV)
    if env:
        return Path(env)
    docs = REPO / "docs"
    return docs / "results" if docs.is_dir() else None


def commit(repo: Path = REPO) -> str:
    """The checkout's commit, or ``unknown``; ``-dirty`` when the code or config that produce results
    (``CODE``) differ from it (edits to the manuals do not change a result)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=repo, capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE], cwd=repo,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head}-dirty" if dirty else head


def command_line(experiment: str, argv: Sequence[str] | None = None) -> str:
    """The command as a user would type it: ``safer-hil experiment <experiment> <args>``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:2] == ["experiment", experiment]:
        args = args[2:]
    return shlex.join(["safer-hil", "experiment", experiment, *args])


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None) -> str:
    """A pipe table of ``rows`` (floats to 4 significant digits, None as ``-``)."""
    cols = list(columns) if columns is not None else list(dict.fromkeys(k for r in rows for k in r))

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v).replace("|", "\\|")

    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def demote(markdown: str) -> str:
    """The command's own headings one level down, under this file's title."""
    return re.sub(r"^(#+) ", r"#\1 ", markdown, flags=re.MULTILINE)


RESULTS_NAME = re.compile(r"[a-z0-9][a-z0-9_-]*")  # a results file's name: docs/results/NAME.md


def bad_results_name(name: str) -> str | None:
    """Why ``name`` cannot name a results file (None: it can), for a command's usage error."""
    if RESULTS_NAME.fullmatch(name):
        return None
    return f"--results-name takes lower-case letters, digits, - and _, got {name!r}"


def _slug(experiment: str) -> str:
    if not RESULTS_NAME.fullmatch(experiment):
        raise ValueError(f"experiment name {experiment!r}: lower-case letters, digits, '-' and '_' only")
    return experiment


def _title(command: str, kind: str, name: str) -> str:
    """The file's title: the command group and experiment that wrote it, and the file's own name
    when another (``--results-name``, e.g. a held-out run of the same experiment)."""
    try:
        words = shlex.split(command)
    except ValueError:
        words = []
    ran = words[2] if len(words) >= 3 and words[:2] == ["safer-hil", kind] else name
    return f"`safer-hil {kind} {ran}`" + ("" if ran == name else f" ({name})")


def write_results(experiment: str, command: str, markdown: str, figures: Sequence[Path] = (), *,
                  now: dt.datetime | None = None, directory: Path | None = None,
                  kind: str = "experiment") -> Path | None:
    """Write ``<results dir>/<experiment>.md``; returns its path (None when there is no results dir).

    ``command`` is the command line that produced the results (:func:`command_line`), ``markdown``
    the command's table (or report), ``figures`` image files to copy beside it and link; ``kind``
    the command group in the title (``experiment``, or ``bench`` for a bench that writes one)."""
    name = _slug(experiment)
    out = directory if directory is not None else results_dir()
    if out is None:
        print(f"safer-hil {kind} {name}: no docs/ directory and ${ENV} unset: no result file written",
              file=sys.stderr)
        return None
    out.mkdir(parents=True, exist_ok=True)
    when = (now or dt.datetime.now(dt.UTC)).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"# Results: {_title(command, kind, name)}",
        "",
        "Written by the command below; rerun it to regenerate this file (do not edit by hand).",
        "",
        f"- date: {when}",
        f"- commit: `{commit()}`",
        f"- command: `{command}`",
        "",
        demote(markdown.strip()),
        "",
    ]
    shown = [Path(f) for f in figures if Path(f).is_file()]
    if shown:
        img = out / "img"
        img.mkdir(exist_ok=True)
        lines += ["## Figures", ""]
        for f in shown:
            target = img / f"{name}_{f.name}"
            shutil.copyfile(f, target)
            lines += [f"![{f.stem}](img/{target.name})", ""]
    path = out / f"{name}.md"
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines), encoding="utf-8")
    tmp.replace(path)
    print(f"results: {path}")
    return path
