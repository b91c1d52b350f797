"""The shape of the code (issue 11, "Done when"): the import graph and module sizes.

The graph is read from the source with ``ast``, never by importing: every ``import`` and
``from ... import`` anywhere in a module counts (module level, inside functions and under
``if TYPE_CHECKING:``). Relative imports are resolved against the importing module's package,
and ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``.
Importing ``a.b.c`` is an edge to ``a.b.c`` only (not to the packages ``a`` and ``a.b`` that
Python also runs), as import-graph tools usually count it.

Each rule is one parametrized case so a failure names the rule and lists every offender.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fsw", "hil_sim", "ground")
MAX_MODULE_LINES = 400


@dataclass(frozen=True)
class Edge:
    """``importer`` imports ``target`` at ``line`` (both dotted module names of the project)."""

    importer: str
    target: str
    line: int

    def __str__(self) -> str:
        return f"{self.importer} -> {self.target} (line {self.line})"


def module_files(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Dotted module name -> source file, for every ``.py`` under the given top-level packages."""
    modules: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _known_prefix(name: str, modules: dict[str, Path]) -> str | None:
    """The longest dotted prefix of ``name`` that is a project module (``a.b.C`` -> ``a.b``)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        candidate = ".".join(parts[:n])
        if candidate in modules:
            return candidate
    return None


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> Iterator[Edge]:
    """Every project module that ``module`` imports, wherever the import statement stands."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                target = _known_prefix(alias.name, modules)
                if target is not None:
                    yield Edge(module, target, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".") if package else []
                if node.level > 1:
                    anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            else:
                base = node.module or ""
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                target = submodule if submodule in modules else _known_prefix(base, modules)
                if target is not None:
                    yield Edge(module, target, node.lineno)


def import_graph(root: Path = ROOT, packages: Iterable[str] = PACKAGES) -> dict[str, list[Edge]]:
    """Module -> its import edges to project modules (self-imports dropped)."""
    modules = module_files(root, packages)
    graph: dict[str, list[Edge]] = {}
    for module, path in modules.items():
        seen: set[str] = set()
        edges = []
        for edge in imports_of(module, path, modules):
            if edge.target != module and edge.target not in seen:
                seen.add(edge.target)
                edges.append(edge)
        graph[module] = edges
    return graph


def strongly_connected(graph: dict[str, list[Edge]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module (the import cycles)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(start: str) -> None:
        # Iterative, so a deep chain of imports cannot hit the recursion limit.
        work: list[tuple[str, Iterator[Edge]]] = [(start, iter(graph.get(start, [])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            for edge in edges:
                nxt = edge.target
                if nxt not in graph:
                    continue
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(graph[nxt])))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        components.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(components)


def shortest_cycle(graph: dict[str, list[Edge]], component: list[str]) -> list[Edge]:
    """One shortest cycle through the component's first module, as the edges that close it."""
    members = set(component)
    start = component[0]
    came: dict[str, Edge] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for edge in graph[node]:
                if edge.target not in members:
                    continue
                if edge.target == start:
                    path = [edge]
                    while path[0].importer != start:
                        path.insert(0, came[path[0].importer])
                    return path
                if edge.target not in came:
                    came[edge.target] = edge
                    following.append(edge.target)
        frontier = following
    raise AssertionError(f"no cycle through {start}")  # pragma: no cover - a component always has one


def describe_cycles(graph: dict[str, list[Edge]], components: list[list[str]]) -> str:
    lines = []
    for component in components:
        lines.append(f"cycle among {len(component)} modules: {', '.join(component)}")
        lines.append("  e.g. " + "  =>  ".join(str(edge) for edge in shortest_cycle(graph, component)))
    return "\n".join(lines)


def _in(module: str, *prefixes: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


# Layer rules of docs/architecture.md: (id, which importers, which targets are forbidden to them).
@dataclass(frozen=True)
class LayerRule:
    name: str
    importers: tuple[str, ...]
    allowed: tuple[str, ...] | None = None  # project modules an importer may use (None: all but `forbidden`)
    forbidden: tuple[str, ...] = ()

    def violates(self, edge: Edge) -> bool:
        if not _in(edge.importer, *self.importers):
            return False
        if _in(edge.target, *self.forbidden):
            return True
        return self.allowed is not None and not _in(edge.target, *self.allowed)


LAYER_RULES = [
    LayerRule("fsw never imports hil_sim or ground", ("fsw",), forbidden=("hil_sim", "ground")),
    LayerRule("framework imports only fsw.framework", ("fsw.framework",), allowed=("fsw.framework",)),
    LayerRule("core imports only core and framework", ("fsw.core",), allowed=("fsw.core", "fsw.framework")),
    LayerRule(
        "comm imports only core, framework and comm",
        ("fsw.comm",),
        allowed=("fsw.core", "fsw.framework", "fsw.comm"),
    ),
    LayerRule(
        "drivers import only framework, comm, core and drivers",
        ("fsw.drivers",),
        allowed=("fsw.framework", "fsw.comm", "fsw.core", "fsw.drivers"),
    ),
    LayerRule(
        "settings import only framework, comm, core, drivers and settings",
        ("fsw.settings", "fsw.sections"),
        # fsw.executive.schedule_check (the flight file's schedule check, which reads the task
        # registry) is the one arrow up left: it belongs in the settings layer, not yet moved
        allowed=("fsw.framework", "fsw.comm", "fsw.core", "fsw.drivers", "fsw.settings", "fsw.sections",
                 "fsw.executive.schedule_check"),
    ),
    LayerRule("tasks never import executive", ("fsw.tasks",), forbidden=("fsw.executive",)),
]


@pytest.fixture(scope="module")
def graph() -> dict[str, list[Edge]]:
    return import_graph()


def test_the_walker_sees_the_project(graph: dict[str, list[Edge]]) -> None:
    """A guard against a walker that passes every rule by finding nothing."""
    assert "fsw.framework.task" in graph and "hil_sim.cli" in graph and "ground.cli" in graph
    assert sum(len(edges) for edges in graph.values()) > 200


@pytest.mark.parametrize("package", ["fsw", "hil_sim", "ground"])
def test_no_import_cycles(graph: dict[str, list[Edge]], package: str) -> None:
    sub = {m: [e for e in edges if _in(e.target, package)] for m, edges in graph.items() if _in(m, package)}
    components = strongly_connected(sub)
    assert not components, f"{len(components)} import cycle(s) in {package}/:\n" + describe_cycles(sub, components)


@pytest.mark.parametrize("rule", LAYER_RULES, ids=[r.name.replace(" ", "_") for r in LAYER_RULES])
def test_layer_rule(graph: dict[str, list[Edge]], rule: LayerRule) -> None:
    offenders = [edge for edges in graph.values() for edge in edges if rule.violates(edge)]
    assert not offenders, f"{rule.name}: {len(offenders)} import(s) break it:\n" + "\n".join(
        f"  {edge}" for edge in sorted(offenders, key=lambda e: (e.importer, e.line))
    )


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_over_400_lines(package: str) -> None:
    sizes = {m: len(p.read_text(encoding="utf-8").splitlines()) for m, p in module_files(ROOT, [package]).items()}
    over = sorted(((n, m) for m, n in sizes.items() if n > MAX_MODULE_LINES), reverse=True)
    assert not over, f"modules in {package}/ over {MAX_MODULE_LINES} lines:\n" + "\n".join(
        f"  {m}: {n}" for n, m in over
    )


# The walker itself, on a small package written for the test.
def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def test_walker_resolves_every_import_form(tmp_path: Path) -> None:
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.a import thing\n",
            "pkg/a.py": "thing = 1\n",
            "pkg/sub/__init__.py": "",
            "pkg/sub/b.py": (
                "from __future__ import annotations\n"
                "from typing import TYPE_CHECKING\n"
                "from .. import a\n"  # relative, a module: pkg.a
                "from . import c as _c\n"  # relative sibling module: pkg.sub.c
                "if TYPE_CHECKING:\n"
                "    from pkg.sub.d import D\n"  # a name in a module: pkg.sub.d
                "def f():\n"
                "    import pkg.e.f\n"  # function level, dotted: pkg.e.f
                "    from ..e import missing\n"  # a name in a package: pkg.e
                "    import numpy\n"  # not the project's: no edge
            ),
            "pkg/sub/c.py": "from pkg import thing\n",  # a name of the package: pkg
            "pkg/sub/d.py": "class D: ...\n",
            "pkg/e/__init__.py": "",
            "pkg/e/f.py": "",
        },
    )
    graph = import_graph(tmp_path, ["pkg"])
    assert {e.target for e in graph["pkg.sub.b"]} == {"pkg.a", "pkg.sub.c", "pkg.sub.d", "pkg.e.f", "pkg.e"}
    assert [e.target for e in graph["pkg.sub.c"]] == ["pkg"]
    assert [e.target for e in graph["pkg"]] == ["pkg.a"]


def test_walker_reports_a_cycle_with_its_path(tmp_path: Path) -> None:
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": "from pkg import b\n",
            "pkg/b.py": "def f():\n    from pkg.c import x\n",
            "pkg/c.py": "import pkg.a\nx = 1\n",
            "pkg/d.py": "import pkg.a\n",
        },
    )
    graph = import_graph(tmp_path, ["pkg"])
    components = strongly_connected(graph)
    assert components == [["pkg.a", "pkg.b", "pkg.c"]]
    text = describe_cycles(graph, components)
    assert "pkg.a -> pkg.b (line 1)  =>  pkg.b -> pkg.c (line 2)  =>  pkg.c -> pkg.a (line 1)" in text


def test_the_settings_rule_refuses_an_arrow_up_to_the_tasks() -> None:
    """The settings layer once imported ``fsw.tasks.sections`` while the tasks import the
    settings; the rule names that arrow (and lets the settings use the layers below)."""
    rule = next(r for r in LAYER_RULES if r.importers == ("fsw.settings", "fsw.sections"))
    assert rule.violates(Edge("fsw.settings", "fsw.tasks.sections", 35))
    assert rule.violates(Edge("fsw.sections", "fsw.executive.topology", 1))
    assert not rule.violates(Edge("fsw.settings", "fsw.sections", 1))
    assert not rule.violates(Edge("fsw.settings", "fsw.drivers.calibration_file", 1))
    assert not rule.violates(Edge("fsw.tasks.base", "fsw.settings", 1))
