"""Drive a step generator (``fsw.core.steps``) to its end, counting its slices: tests that a
long computation is cut into bounded steps (``fsw.core.steps.run_to_end`` when the count does
not matter)."""

from __future__ import annotations

from collections.abc import Generator
from typing import TypeVar

T = TypeVar("T")


def count_steps(gen: Generator[None, None, T]) -> tuple[int, T]:
    """Run ``gen`` to its end: (how many times it yielded, its value)."""
    yields = 0
    while True:
        try:
            next(gen)
        except StopIteration as stop:
            return yields, stop.value  # type: ignore[no-any-return]
        yields += 1
