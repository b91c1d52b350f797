"""Fixtures of the ground-link tests: a signing key, the demo task kind, an in-memory link.

Helpers live in ``tests/support/ground_demo.py`` (a unique module name): ``conftest`` is not importable by
name in a suite with several conftest files."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "support"))

import ground_demo  # noqa: E402
from ground_demo import MemoryLink  # noqa: E402

from fsw.comm.mavlink_signing import write_key  # noqa: E402
from fsw.registry import KINDS  # noqa: E402


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    """A fresh signing key in a temporary file (never a key from the repository)."""
    path = tmp_path / "rover.key"
    write_key(path)
    return path


@pytest.fixture
def demo_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(KINDS, *ground_demo.DEMO_KIND)


@pytest.fixture
def memory_link() -> MemoryLink:
    return MemoryLink()
