"""Every project module named in an import, including the lazy ones inside functions (which
no import of the file runs), exists: a module moved without its callers fails here, not in
the middle of an experiment."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fsw", "hil_sim", "ground")


def _imported(path: Path) -> list[tuple[int, str, list[str]]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            out.extend((node.lineno, a.name, []) for a in node.names)
    return [(n, m, names) for n, m, names in out if m.split(".")[0] in PACKAGES]


def test_every_project_import_names_a_module_that_exists() -> None:
    missing = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for line, module, names in _imported(path):
                if importlib.util.find_spec(module) is None:
                    missing.append(f"{path.relative_to(ROOT)}:{line}: {module}")
                    continue
                for name in names:  # a submodule imported by name must exist too
                    sub = f"{module}.{name}"
                    base = ROOT / Path(*module.split("."))
                    if base.is_dir() and not (base / f"{name}.py").exists() and not (base / name).is_dir():
                        continue  # a name defined in the package's __init__
                    if base.is_dir() and importlib.util.find_spec(sub) is None:
                        missing.append(f"{path.relative_to(ROOT)}:{line}: {sub}")
    assert not missing, "\n".join(missing)
