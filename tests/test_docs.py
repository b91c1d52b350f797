"""The docs are manuals that resolve: every citation of the algorithm reference names a section
of ``docs/algorithm.md``, every file a text cites ships with the repository, the reference's
equation -> function table names functions that exist, and no page reads like a lab diary."""

from __future__ import annotations

import ast
import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALGORITHM = ROOT / "docs" / "algorithm.md"
# Where citations live: the programs, their config, the manuals, the tests, the two root pages.
CITING = ("fsw/", "hil_sim/", "ground/", "config/", "docs/", "tests/", "README.md", "CHANGELOG.md")
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".ini", ".dbc", ".json", ""}
THIS = Path(__file__).resolve()

SECTION_RE = re.compile(r"§\s*(\d+(?:\.\d+)*)")
NAMED_RE = re.compile(r"algorithm\.md,\s*\"([^\"]+)\"", re.IGNORECASE)
DOC_PATH_RE = re.compile(
    r"(?<![\w/.-])((?:docs|config|tests|fsw|hil_sim|ground)/[\w./-]+\.(?:md|toml|dbc|py|yaml|npz|json))\b")
# Result files exist once their command ran; a manual may name one in prose (a link must resolve).
WRITTEN_BY_COMMANDS = "docs/results/"
LINK_RE = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
# Pages that are not in the repository: the project's reference is docs/algorithm.md, its
# design page docs/architecture.md.
ABSENT = ("ALGORITHM.md", "ARCHITECTURE.md", "STYLE.md")


@cache
def tracked() -> tuple[Path, ...]:
    """The repository's files under CITING (git's list; the tree walked if git is missing)."""
    try:
        out = subprocess.run(["git", "ls-files", *CITING], cwd=ROOT, capture_output=True, text=True, check=True)
        names = [ROOT / n for n in out.stdout.splitlines()]
    except (OSError, subprocess.CalledProcessError):
        names = [p for c in CITING for p in ((ROOT / c).rglob("*") if c.endswith("/") else [ROOT / c])]
    files = [p for p in names if p.is_file() and p.suffix in TEXT_SUFFIXES and p.resolve() != THIS]
    return tuple(sorted(files))


@cache
def texts() -> tuple[tuple[Path, str], ...]:
    out = []
    for p in tracked():
        try:
            out.append((p, p.read_text(encoding="utf-8")))
        except UnicodeDecodeError:
            continue
    return tuple(out)


@cache
def headings() -> tuple[frozenset[str], tuple[str, ...]]:
    """Section numbers (``"3.1"``) and heading titles of docs/algorithm.md."""
    numbers, titles = set(), []
    for line in ALGORITHM.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^#{1,4}\s+(.*)$", line)
        if not m:
            continue
        titles.append(m.group(1).strip())
        n = re.match(r"(\d+(?:\.\d+)*)\.?\s", m.group(1))
        if n:
            numbers.add(n.group(1))
    return frozenset(numbers), tuple(titles)


def where(p: Path, text: str, pos: int) -> str:
    return f"{p.relative_to(ROOT)}:{text.count(chr(10), 0, pos) + 1}"


def test_algorithm_reference_keeps_the_cited_section_numbers() -> None:
    numbers, _ = headings()
    for n in ("1", "1.1", "1.2", "2", "3", "3.1", "3.2", "3.3", "3.4", "3.5", "3.6", "4", "5", "5.1", "6",
              "6.1", "6.2", "6.3", "6.4", "6.5", "6.6", "7", "8"):
        assert n in numbers, f"docs/algorithm.md has no section {n}"


def test_every_section_citation_resolves() -> None:
    numbers, titles = headings()
    bad = []
    for p, text in texts():
        for m in SECTION_RE.finditer(text):
            if m.group(1) not in numbers:
                bad.append(f"{where(p, text, m.start())}: §{m.group(1)}")
        for m in NAMED_RE.finditer(text):
            name = " ".join(m.group(1).split()).lower()
            if not any(name in t.lower() for t in titles):
                bad.append(f"{where(p, text, m.start())}: \"{name}\"")
    assert not bad, "citations of sections docs/algorithm.md does not have:\n" + "\n".join(bad)


def test_no_citation_of_a_page_outside_the_repository() -> None:
    bad = []
    for p, text in texts():
        for name in ABSENT:
            for m in re.finditer(rf"(?<![\w/]){re.escape(name)}", text):
                bad.append(f"{where(p, text, m.start())}: {name}")
    assert not bad, "cites pages that do not ship (use docs/algorithm.md, docs/architecture.md):\n" + "\n".join(bad)


def test_cited_docs_and_config_files_exist() -> None:
    bad = []
    for p, text in texts():
        for m in DOC_PATH_RE.finditer(text):
            target = m.group(1).rstrip(".")
            if not target.startswith(WRITTEN_BY_COMMANDS) and not (ROOT / target).exists():
                bad.append(f"{where(p, text, m.start())}: {target}")
        if p.suffix == ".md":
            for m in LINK_RE.finditer(text):
                target = m.group(1)
                if "://" in target or target.startswith("mailto:"):
                    continue
                if not (p.parent / target).exists():
                    bad.append(f"{where(p, text, m.start())}: link {target}")
    assert not bad, "cited files absent from the repository:\n" + "\n".join(bad)


def table_rows() -> list[tuple[str, str]]:
    """``(path, qualified name)`` of every row of the equation -> function table."""
    text = ALGORITHM.read_text(encoding="utf-8")
    table = text[text.index("## Equation -> function"):]
    rows = re.findall(r"^\|[^|]*\|[^|]*\|\s*`([\w/.]+\.py):([\w.]+)`\s*\|\s*$", table, re.MULTILINE)
    return [(a, b) for a, b in rows]


def defines(path: Path, qualname: str) -> bool:
    """Whether ``path`` defines ``qualname`` (a class, a function, or a method of a class)."""
    scope: list[ast.stmt] = list(ast.parse(path.read_text(encoding="utf-8")).body)
    for part in qualname.split("."):
        found = None
        for node in scope:
            if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.name == part:
                found = node
        if found is None:
            return False
        scope = list(found.body)
    return True


def test_equation_table_is_complete() -> None:
    rows = table_rows()
    assert len(rows) >= 60, "the equation -> function table lost rows (or its format changed)"
    cited = set(re.findall(r"^\| (§[\d.]+|Mars)", ALGORITHM.read_text(encoding="utf-8"), re.MULTILINE))
    numbers, _ = headings()
    for n in numbers - {"8"}:
        if "." in n or n in {"2", "4", "7"}:
            assert f"§{n}" in cited, f"no function for §{n} in the equation -> function table"


@pytest.mark.parametrize(("path", "name"), table_rows())
def test_equation_table_names_a_function_that_exists(path: str, name: str) -> None:
    file = ROOT / path
    assert file.is_file(), f"{path} does not exist"
    assert defines(file, name), f"{path} defines no {name}"


# A manual says what the software does; history lives in git and CHANGELOG.md, measured figures
# in the result files an experiment command writes (docs/results/).
DIARY = [
    (re.compile(r"\b(first|second|third|fourth|fifth|sixth|seventh|eighth|this|that|other|previous|earlier|later|"
                r"last|next|work)[- ]sessions?\b|\bsessions?\s+\d", re.IGNORECASE), "a work session"),
    (re.compile(r"\(was\s"), "a before/was note"),
    (re.compile(r"^#+ .*\b20\d\d-\d\d-\d\d\b", re.MULTILINE), "a dated heading"),
    (re.compile(r"\b(measured|remeasured)\s+20\d\d-\d\d-\d\d", re.IGNORECASE), "a dated measurement"),
    (re.compile(r"^#+ .*\b(Earlier|Before)\b", re.MULTILINE), "an earlier-results section"),
]


def manuals() -> list[Path]:
    return sorted(p for p in (ROOT / "docs").glob("*.md"))


@pytest.mark.parametrize("page", manuals(), ids=lambda p: p.name)
def test_manual_has_no_diary(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    bad = [f"{where(page, text, m.start())}: {what}: {m.group(0)!r}" for rx, what in DIARY for m in rx.finditer(text)]
    assert not bad, "\n".join(bad)


def test_one_results_section_per_experiment() -> None:
    """No manual carries several result sections for one experiment (they belong to docs/results/)."""
    for page in manuals():
        heads = re.findall(r"^#+ (?:Results|Measured)\b.*$", page.read_text(encoding="utf-8"), re.MULTILINE)
        assert len(heads) <= 1, f"{page.name}: {heads}"


def test_diary_check_catches_a_diary() -> None:
    sample = "## Results (measured 2026-11-24, fourth session)\nthe rate (was 3 Hz) is 5 Hz\n"
    assert {what for rx, what in DIARY if rx.search(sample)} >= {"a work session", "a before/was note",
                                                                 "a dated heading", "a dated measurement"}
    legit = "STATUS keep-alive on an idle open session; a new session sends only the missing segments\n"
    assert not [what for rx, what in DIARY if rx.search(legit)]


def test_config_reference_is_current() -> None:
    """docs/config.md is what ``safer-fsw config-keys`` prints (regenerate: safer-fsw config-keys > docs/config.md)."""
    from fsw.cli import config_reference

    page = (ROOT / "docs" / "config.md").read_text(encoding="utf-8")
    assert page == config_reference(), "docs/config.md is stale: run `safer-fsw config-keys > docs/config.md`"


def test_config_reference_covers_every_key_of_the_default_config() -> None:
    import tomllib

    from fsw.framework.params_table import config_keys
    from fsw.settings import DEFAULT_CONFIG, FswConfig

    documented = {f"{r.section}.{r.key}" for r in config_keys(FswConfig)}

    def keys(table: dict[str, object], prefix: str) -> set[str]:
        out = set()
        for k, v in table.items():
            if isinstance(v, dict):
                out |= keys(v, f"{prefix}{k}.")
            elif not (isinstance(v, list) and v and isinstance(v[0], dict)):
                out.add(f"{prefix}{k}")
        return out

    with DEFAULT_CONFIG.open("rb") as fh:
        present = keys(tomllib.load(fh), "")
    present |= {f"executive.{k}" for k in ("groups", "tasks")}
    assert present <= documented, sorted(present - documented)


def test_cited_manual_sections_exist() -> None:
    """``docs/perception.md, "Geofence"``: the quoted heading exists in that page."""
    rx = re.compile(r"\b([a-z][\w-]*)\.md,?\s+\"([^\"\n]+)\"")
    bad = []
    for p, text in texts():
        for m in rx.finditer(text):
            page = ROOT / "docs" / f"{m.group(1)}.md"
            if not page.is_file():
                continue
            heads = [h.lower() for h in re.findall(r"^#+\s+(.*)$", page.read_text(encoding="utf-8"), re.MULTILINE)]
            want = " ".join(m.group(2).split()).lower()
            if not any(want in h for h in heads):
                bad.append(f"{where(p, text, m.start())}: {m.group(1)}.md, \"{m.group(2)}\"")
    assert not bad, "citations of sections that do not exist:\n" + "\n".join(bad)


def test_bench_config_reference_is_current() -> None:
    """docs/hil-config.md is what ``python -m hil_sim.config_reference`` prints."""
    from hil_sim.config_reference import reference

    page = (ROOT / "docs" / "hil-config.md").read_text(encoding="utf-8")
    assert page == reference(), "stale: run `python -m hil_sim.config_reference > docs/hil-config.md`"


def test_test_files_named_in_the_manuals_exist() -> None:
    names = {p.name for p in (ROOT / "tests").rglob("test_*.py")}
    bad = []
    for page in [*manuals(), ROOT / "README.md"]:
        text = page.read_text(encoding="utf-8")
        bad += [f"{where(page, text, m.start())}: {m.group(0)}" for m in re.finditer(r"\btest_\w+\.py\b", text)
                if m.group(0) not in names]
    assert not bad, "\n".join(bad)


def test_dotted_module_names_in_the_manuals_exist() -> None:
    """``fsw.core.codec.quadtree.lowpass``: packages down to a module of the repository, then an
    attribute path (not checked); a name under a package that is no module of it is stale."""
    rx = re.compile(r"(?<![\w/.-])((?:fsw|hil_sim|ground)(?:\.[A-Za-z_]\w*)+)")
    file_names = {"toml", "md", "csv", "json", "tlog", "png", "npy", "py", "yaml", "log", "txt", "dbc", "ckpt"}
    bad = []
    for page in [*manuals(), ROOT / "README.md"]:
        text = page.read_text(encoding="utf-8")
        for m in rx.finditer(text):
            parts = m.group(1).split(".")
            if parts[-1] in file_names:
                continue  # a file name such as fsw.toml or ground.md
            base = ROOT
            for part in parts:
                if (base / part).is_dir():
                    base = base / part
                    continue
                if not (base / f"{part}.py").is_file():
                    bad.append(f"{where(page, text, m.start())}: {m.group(1)}")
                break
    assert not bad, "module paths that do not exist:\n" + "\n".join(bad)
