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
import functools
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fsw", "hil_sim", "ground")


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


def parse(path: Path) -> ast.Module:
    """The module's syntax tree, parsed once per version of the file (the rules below each walk
    every module of the project: parsing them once for all the rules is most of their cost)."""
    st = path.stat()
    return _parse(path, st.st_mtime_ns, st.st_size)


@functools.cache
def _parse(path: Path, _mtime_ns: int, _size: int) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


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
    tree = parse(path)
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
        # the settings layer: the configuration, its sections, the agents' task tables (task
        # classes named as strings, imported lazily) and the schedule check that reads them
        ("fsw.settings", "fsw.sections", "fsw.registry", "fsw.schedule_check"),
        allowed=("fsw.framework", "fsw.comm", "fsw.core", "fsw.drivers", "fsw.settings", "fsw.sections",
                 "fsw.registry", "fsw.schedule_check"),
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


# -- modules split by meaning ---------------------------------------------------------------------
MAX_FOLDER_MODULES = 15
# Folders over the limit today, with the most modules they may hold until they are split:
# hil_sim/world's terrain and rendering parts, fsw/comm's MAVLink files, fsw/drivers's CAN
# transports and fsw/tasks's mission and motion parts to packages of their own (issue 24, item 2).
FOLDER_ALLOWANCE = {"hil_sim/world": 23, "fsw/comm": 25, "fsw/drivers": 17, "fsw/tasks": 25}


def folders(root: Path, packages: Iterable[str]) -> dict[str, int]:
    """Folder (relative, ``/``-separated) -> its Python modules (``__init__`` not counted)."""
    out: dict[str, int] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            if path.name != "__init__.py":
                key = path.parent.relative_to(root).as_posix()
                out[key] = out.get(key, 0) + 1
    return out


def folder_offenders(root: Path, packages: Iterable[str], allowance: dict[str, int]) -> list[str]:
    return [f"{d}: {n} modules (limit {allowance.get(d, MAX_FOLDER_MODULES)})"
            for d, n in sorted(folders(root, packages).items()) if n > allowance.get(d, MAX_FOLDER_MODULES)]


def _trees(root: Path, packages: Iterable[str]) -> Iterator[tuple[str, ast.Module]]:
    for module, path in module_files(root, packages).items():
        yield module, parse(path)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def bolted_functions(root: Path, packages: Iterable[str]) -> list[str]:
    """Module-level functions that take a ``self``: methods written outside their class."""
    out = []
    for module, tree in _trees(root, packages):
        for node in tree.body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                names = [a.arg for a in (*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs)]
                if "self" in names:
                    out.append(f"{module}.{node.name} (line {node.lineno})")
    return out


def type_checking_stubs(root: Path, packages: Iterable[str]) -> list[str]:
    """``if TYPE_CHECKING:`` blocks that declare anything but imports (method or attribute stubs)."""
    out = []
    for module, tree in _trees(root, packages):
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                for stmt in [*node.body, *node.orelse]:
                    if not isinstance(stmt, ast.Import | ast.ImportFrom | ast.Pass):
                        out.append(f"{module} line {stmt.lineno}: {type(stmt).__name__} under TYPE_CHECKING")
    return out


_NOT_MIXINS = {"Protocol", "TypedDict", "NamedTuple", "Enum", "StrEnum", "IntEnum"}


def _base_names(cls: ast.ClassDef) -> list[str]:
    names = []
    for b in cls.bases:
        target = b.value if isinstance(b, ast.Subscript) else b
        if isinstance(target, ast.Name):
            names.append(target.id)
        elif isinstance(target, ast.Attribute):
            names.append(target.attr)
    return names


def _self_assigned(cls: ast.ClassDef) -> set[str]:
    """Attributes the class's own methods assign on ``self``."""
    out = set()
    for node in ast.walk(cls):
        targets: list[ast.expr] = []
        if isinstance(node, ast.Assign):
            targets = list(node.targets)
        elif isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        for t in targets:
            for sub in ast.walk(t):
                if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id == "self":
                    out.add(sub.attr)
    return out


def mixins_declaring_host_attributes(root: Path, packages: Iterable[str]) -> list[str]:
    """Classes that declare attributes (``x: T`` without a value) they never set themselves and
    that a class deriving from them sets: a mixin redeclaring its host's attributes. Protocols,
    dataclasses, typed dicts and named tuples declare fields on purpose and are not counted."""
    classes: dict[str, tuple[str, ast.ClassDef]] = {}
    for module, tree in _trees(root, packages):
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                classes.setdefault(node.name, (module, node))
    out = []
    for name, (module, cls) in sorted(classes.items()):
        if _NOT_MIXINS & set(_base_names(cls)) or any(
            "dataclass" in ast.unparse(d) for d in cls.decorator_list
        ):
            continue
        declared = {s.target.id for s in cls.body
                    if isinstance(s, ast.AnnAssign) and s.value is None and isinstance(s.target, ast.Name)
                    and not ast.unparse(s.annotation).startswith("ClassVar")}
        declared -= _self_assigned(cls)
        if not declared:
            continue
        for sub_module, sub in classes.values():
            if name in _base_names(sub):
                host = sorted(declared & _self_assigned(sub))
                if host:
                    out.append(f"{module}.{name} declares {', '.join(host)} that {sub_module}.{sub.name} sets")
    return out


def wing_graph(graph: dict[str, list[Edge]], root: str = "fsw.core") -> dict[str, list[Edge]]:
    """The import graph of ``root``'s sub-packages (wings): an edge where a module of one wing
    imports a module of another (modules directly in ``root`` are wings of their own)."""
    def wing(module: str) -> str:
        rest = module[len(root) + 1:].split(".")
        return f"{root}.{rest[0]}"

    wings: dict[str, list[Edge]] = {}
    for module, edges in graph.items():
        if not _in(module, root) or module == root:
            continue
        w = wing(module)
        out = wings.setdefault(w, [])
        for e in edges:
            other = wing(e.target) if _in(e.target, root) and e.target != root else w
            if other != w and all(x.target != other for x in out):
                out.append(Edge(w, other, e.line))
    return wings


@pytest.mark.parametrize("package", PACKAGES)
def test_no_folder_of_more_than_15_modules(package: str) -> None:
    offenders = folder_offenders(ROOT, [package], FOLDER_ALLOWANCE)
    assert not offenders, "folders to split into packages:\n" + "\n".join(f"  {o}" for o in offenders)


def test_the_folder_allowances_are_still_needed() -> None:
    """An allowance is removed once its folder is split."""
    sizes = folders(ROOT, PACKAGES)
    stale = {d: n for d, n in FOLDER_ALLOWANCE.items() if sizes.get(d, 0) <= MAX_FOLDER_MODULES}
    assert not stale, f"remove from FOLDER_ALLOWANCE (now within the limit): {stale}"


def test_no_methods_bolted_on_from_module_level() -> None:
    offenders = bolted_functions(ROOT, PACKAGES)
    assert not offenders, "module-level functions with a self parameter:\n" + "\n".join(f"  {o}" for o in offenders)


def test_no_type_checking_stubs() -> None:
    offenders = type_checking_stubs(ROOT, PACKAGES)
    assert not offenders, "TYPE_CHECKING blocks with declarations:\n" + "\n".join(f"  {o}" for o in offenders)


# Mixins still waiting to become composed objects (in files under other work: the MAVLink uplink).
KNOWN_MIXINS: tuple[str, ...] = ()


def test_no_mixin_redeclares_its_hosts_attributes() -> None:
    found = mixins_declaring_host_attributes(ROOT, PACKAGES)
    assert all(any(o.startswith(k + " ") for o in found) for k in KNOWN_MIXINS), "remove from KNOWN_MIXINS"
    offenders = [o for o in found if not o.startswith(tuple(k + " " for k in KNOWN_MIXINS))]
    assert not offenders, "mixins (compose an object with a typed interface instead):\n" + "\n".join(
        f"  {o}" for o in offenders)


def test_the_core_wings_form_a_dag(graph: dict[str, list[Edge]]) -> None:
    wings = wing_graph(graph)
    assert len(wings) >= 8, sorted(wings)  # stereo, map, registration, localization, edge, planning, codec, motion
    components = strongly_connected(wings)
    assert not components, "the core's wings import each other in a circle:\n" + describe_cycles(wings, components)


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


def test_the_shape_rules_find_what_they_forbid(tmp_path: Path) -> None:
    """Each rule on a small package that breaks it once (and a Protocol and a dataclass it must not flag)."""
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/bolt.py": "from typing import Any\ndef save(self: Any) -> None: ...\ndef ok(x: int) -> int: ...\n",
            "pkg/stubs.py": (
                "from typing import TYPE_CHECKING\n"
                "if TYPE_CHECKING:\n    from pkg.bolt import ok\n"  # an import: allowed
                "class A:\n"
                "    if TYPE_CHECKING:\n        def _goto(self) -> None: ...\n"
            ),
            "pkg/mix.py": (
                "from dataclasses import dataclass\nfrom typing import Protocol\n"
                "class Mixin:\n    step: int\n    def bump(self) -> None:\n        print(self.step)\n"
                "class Host(Mixin):\n    def __init__(self) -> None:\n        self.step = 0\n"
                "class Iface(Protocol):\n    step: int\n"
                "class Impl(Iface):\n    def __init__(self) -> None:\n        self.step = 1\n"
                "@dataclass\nclass Rec:\n    step: int\n"
                "class Sub(Rec):\n    def __init__(self) -> None:\n        self.step = 2\n"
            ),
            "pkg/core/__init__.py": "",
            "pkg/core/a/__init__.py": "",
            "pkg/core/a/x.py": "from pkg.core.b import y\n",
            "pkg/core/b/__init__.py": "",
            "pkg/core/b/y.py": "import pkg.core.a.x\n",
            **{f"pkg/many/m{i}.py": "" for i in range(MAX_FOLDER_MODULES + 1)},
        },
    )
    assert bolted_functions(tmp_path, ["pkg"]) == ["pkg.bolt.save (line 2)"]
    assert type_checking_stubs(tmp_path, ["pkg"]) == ["pkg.stubs line 6: FunctionDef under TYPE_CHECKING"]
    assert mixins_declaring_host_attributes(tmp_path, ["pkg"]) == ["pkg.mix.Mixin declares step that pkg.mix.Host sets"]
    wings = wing_graph(import_graph(tmp_path, ["pkg"]), "pkg.core")
    assert strongly_connected(wings) == [["pkg.core.a", "pkg.core.b"]]
    assert folder_offenders(tmp_path, ["pkg"], {}) == [f"pkg/many: {MAX_FOLDER_MODULES + 1} modules (limit 15)"]
    assert folder_offenders(tmp_path, ["pkg"], {"pkg/many": 16}) == []


MAX_ANY_EXCEPTIONS = 29  # lowered as modules leave the list


def test_explicit_any_is_refused_in_fsw_but_where_still_spelled_out() -> None:
    """mypy refuses an explicit ``Any`` (also implied, as in a bare ``np.ndarray``) in all of fsw/;
    the flight tasks, the executive and the settings are never excepted."""
    import tomllib

    mypy = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    on = [o for o in mypy["overrides"] if o.get("disallow_any_explicit") is True]
    assert any("fsw.*" in o["module"] for o in on)
    excepted = [m for o in mypy["overrides"] if o.get("disallow_any_explicit") is False for m in o["module"]]
    assert not any(m.startswith(("fsw.tasks", "fsw.executive", "fsw.settings", "fsw.app")) for m in excepted)
    assert len(excepted) <= MAX_ANY_EXCEPTIONS, f"{len(excepted)} modules excepted: none joins the list"


def test_the_settings_rule_refuses_an_arrow_up_to_the_tasks() -> None:
    """The settings layer once imported ``fsw.tasks.sections`` while the tasks import the
    settings; the rule names that arrow (and lets the settings use the layers below)."""
    rule = next(r for r in LAYER_RULES if "fsw.settings" in r.importers)
    assert rule.violates(Edge("fsw.settings", "fsw.tasks.sections", 35))
    assert rule.violates(Edge("fsw.sections", "fsw.executive.topology", 1))
    assert not rule.violates(Edge("fsw.settings", "fsw.sections", 1))
    assert not rule.violates(Edge("fsw.settings", "fsw.drivers.calibration_file", 1))
    assert not rule.violates(Edge("fsw.tasks.base", "fsw.settings", 1))


def test_the_flight_software_never_imports_the_lab_tables_library() -> None:
    """pandas is the lab's (hil_sim/lab, the ``lab`` extra): no fsw module imports it."""
    offenders = []
    for module, tree in _trees(ROOT, ["fsw"]):
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            offenders += [f"{module}: {n}" for n in names if n.split(".")[0] == "pandas"]
    assert not offenders, offenders
