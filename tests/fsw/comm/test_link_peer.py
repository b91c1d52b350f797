"""Two-way map sync: each agent a sender and a receiver on one radio (issue 26, item 1), stepped clock."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.comm.link import LinkConfig
from fsw.comm.link_peer import LinkPeer
from fsw.comm.link_sender import SenderState
from hil_sim.link.radio_channel import RadioChannel, RadioChannelConfig

LINK = LinkConfig()
LOSSY = RadioChannelConfig(loss=0.2, ber=1e-5, duplicate=0.05, reorder=0.05)


def _map(n: int, seed: int) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


def _sync(seed: int, restart: tuple[str, float] | None = None, t_max_s: float = 300.0):
    """Agents a and b send each other a map at once; ``restart``: (agent, time) it reboots
    (1 s down: everything arriving is lost; then a new peer offers its map again)."""
    maps = {"a": _map(9000, 1), "b": _map(7000, 2)}
    ch = RadioChannel(LOSSY, seed)
    peers = {s: LinkPeer(LINK, session=1) for s in "ab"}
    for s, p in peers.items():
        p.tx.start(10 if s == "a" else 20, maps[s], 0.0)
    got: dict[str, bytes] = {}
    out_bytes = {"a": 0, "b": 0}
    down: dict[str, float] = {}
    t = 0.0
    while t < t_max_s and not (len(got) == 2 and all(p.tx.state is SenderState.DONE for p in peers.values())):
        if restart is not None and t >= restart[1] and restart[0] not in down and restart[1] >= 0:
            down[restart[0]] = t + 1.0
            restart = (restart[0], -1.0)
        for s in list(down):
            if t >= down[s]:
                del down[s]
                peers[s] = LinkPeer(LINK, session=1)
                peers[s].tx.start(10 if s == "a" else 20, maps[s], t)
        for s, p in peers.items():
            for d in ch.receive(s, t):
                if s not in down:
                    p.receive(d, t)
            if s in down:
                continue
            for d in p.poll(t):
                out_bytes[s] += len(d)
                ch.send(s, d, t)
            m = p.rx.take_map()
            if m is not None:
                got[s] = m[1]
        nxt = [x for x in [*(p.next_deadline_s() for s, p in peers.items() if s not in down),
                           ch.next_arrival_s(), *down.values()] if x is not None]
        t = max(t + 1e-4, min(nxt)) if nxt else t + 0.01
    return maps, got, peers, out_bytes, t


@pytest.mark.parametrize("seed", range(5))
def test_two_agents_exchange_maps_both_ways_on_one_radio(seed: int) -> None:
    maps, got, peers, out_bytes, t = _sync(seed)
    assert got == {"a": maps["b"], "b": maps["a"]}  # each has the other's map, bit-exact
    assert all(p.tx.state is SenderState.DONE for p in peers.values())
    for s in "ab":  # both ends of an agent together never exceed the radio's rate
        assert 8.0 * out_bytes[s] <= LINK.rate_bps * t + 8 * 600


@pytest.mark.parametrize("agent", ["a", "b"])
def test_a_restarted_agent_recovers_both_directions(agent: str) -> None:
    maps, got, peers, _, t = _sync(3, restart=(agent, 4.0))
    assert got == {"a": maps["b"], "b": maps["a"]}
    assert all(p.tx.state is SenderState.DONE for p in peers.values())
    other = "b" if agent == "a" else "a"
    assert peers[other].tx.stats.reoffers >= 1  # its receiver had lost the session
    assert t < 60.0
