"""Step generators: long computations written as generators that yield between bounded steps,
so the executive can run them as slack jobs (fsw/framework/jobs.py); the same code runs at
once where time does not matter (tests, benches) through :func:`run_to_end`."""

from __future__ import annotations

from collections.abc import Generator
from typing import TypeVar

T = TypeVar("T")


def run_to_end(gen: Generator[None, None, T]) -> T:
    """Drive a step generator to its end and return its value."""
    while True:
        try:
            next(gen)
        except StopIteration as stop:
            return stop.value  # type: ignore[no-any-return]
