"""A small software bus: topics, bounded mailboxes and an explicit full-queue policy.

Every subscriber owns a :class:`Mailbox` of fixed depth. When it is full the policy says
what gives: ``drop_newest`` refuses the incoming message, ``drop_oldest`` evicts the
oldest. Either way the drop is counted and reported through ``on_drop`` (the executive
turns it into a throttled event); nothing is ever queued without bound.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, Generic, Literal, TypeVar

M = TypeVar("M")
Policy = Literal["drop_newest", "drop_oldest"]


class Mailbox(Generic[M]):
    """A bounded FIFO with a drop policy and counters."""

    def __init__(
        self,
        name: str,
        depth: int,
        policy: Policy = "drop_oldest",
        on_drop: Callable[[Mailbox[Any]], None] | None = None,
    ) -> None:
        if depth < 1:
            raise ValueError("mailbox depth must be at least 1")
        if policy not in ("drop_newest", "drop_oldest"):
            raise ValueError(f"unknown full-queue policy {policy!r}")
        self.name, self.depth, self.policy = name, depth, policy
        self._q: deque[M] = deque()
        self.on_drop = on_drop
        self.received = 0
        self.dropped = 0
        self.high_water = 0

    def put(self, msg: M) -> bool:
        """Queue ``msg``; returns False if a message (this one or the oldest) was dropped."""
        self.received += 1
        dropped = False
        if len(self._q) >= self.depth:
            self.dropped += 1
            dropped = True
            if self.policy == "drop_newest":
                if self.on_drop:
                    self.on_drop(self)
                return False
            self._q.popleft()
        self._q.append(msg)
        self.high_water = max(self.high_water, len(self._q))
        if dropped and self.on_drop:
            self.on_drop(self)
        return not dropped

    def get(self) -> M | None:
        return self._q.popleft() if self._q else None

    def drain(self) -> list[M]:
        items = list(self._q)
        self._q.clear()
        return items

    def latest(self) -> M | None:
        """The newest message, discarding older ones (for state-like topics)."""
        if not self._q:
            return None
        last = self._q[-1]
        self._q.clear()
        return last

    def __len__(self) -> int:
        return len(self._q)


class SoftwareBus:
    """Publish/subscribe by topic name; each subscriber gets its own bounded mailbox."""

    def __init__(self, default_depth: int = 8, on_drop: Callable[[Mailbox[Any]], None] | None = None) -> None:
        self.default_depth = default_depth
        self.on_drop = on_drop
        self._subs: dict[str, list[Mailbox[Any]]] = {}
        self.published: dict[str, int] = {}

    def subscribe(
        self, topic: str, subscriber: str, depth: int | None = None, policy: Policy = "drop_oldest"
    ) -> Mailbox[Any]:
        box: Mailbox[Any] = Mailbox(f"{topic}->{subscriber}", depth or self.default_depth, policy, self.on_drop)
        self._subs.setdefault(topic, []).append(box)
        return box

    def publish(self, topic: str, msg: Any) -> int:
        """Deliver to every subscriber; returns how many accepted it without a drop."""
        self.published[topic] = self.published.get(topic, 0) + 1
        return sum(box.put(msg) for box in self._subs.get(topic, ()))

    def mailboxes(self) -> list[Mailbox[Any]]:
        return [b for boxes in self._subs.values() for b in boxes]
