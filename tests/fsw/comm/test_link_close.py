"""The link's close, on a stepped clock (issue 12, item 4).

The receiver keeps answering the close after it has the map; the sender treats the map as
delivered as soon as the whole-map acknowledgement (FIN(VERIFIED)) arrives and gives up the
close after ``close_tries`` FIN_ACKs, with an event. No state waits for ``give_up_s`` once
the map is known delivered.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver, ReceiverState
from fsw.comm.link_sender import LinkSender, SenderState
from hil_sim.lab.link_sim import run_transfer
from hil_sim.link.radio_channel import RadioChannelConfig

LINK = LinkConfig()
HARSH = RadioChannelConfig(loss=0.3, ber=1e-5, duplicate=0.1, reorder=0.1, reorder_delay_s=1.0)


def _payload(n: int, seed: int = 0) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


@pytest.mark.parametrize("seed", range(40))
def test_close_at_30_percent_loss_is_prompt_and_bounded(seed: int) -> None:
    """The sender is DONE soon after the receiver has the map; both ends close by themselves."""
    data = _payload(6000, seed)
    r = run_transfer(data, LINK, HARSH, seed=seed, close=True)
    assert r.delivered == data
    assert r.sender_state is SenderState.DONE
    assert r.delivered_s is not None and r.sender_done_s is not None
    assert r.sender_done_s - r.delivered_s <= 10.0
    assert r.receiver_closed_s is not None
    assert r.receiver_closed_s - r.delivered_s <= LINK.fin_linger_s + 1e-6
    assert r.end_s < r.delivered_s + LINK.fin_linger_s + 5.0  # nowhere near give_up_s
    assert r.idle_steps == 0


def _run(tx: LinkSender, rx: LinkReceiver, t0: float, t1: float, step_s: float,
         drop_to_tx: bool = False) -> float:
    t = t0
    while t < t1:
        for d in tx.poll(t):
            rx.receive(d, t)
        for d in rx.poll(t):
            if not drop_to_tx:
                tx.receive(d, t)
        t += step_s
    return t


def _small_pair(cfg: LinkConfig, data: bytes) -> tuple[LinkSender, LinkReceiver]:
    tx, rx = LinkSender(cfg, session=7), LinkReceiver(cfg)
    tx.start(3, data, 0.0)
    return tx, rx


def test_every_fin_lost_until_the_linger_ended_sender_still_learns_delivery() -> None:
    """The case of issue 12: every final acknowledgement lost while the receiver lingered.

    After the linger the receiver still answers the session's PINGs with FIN(VERIFIED), so
    the sender is DONE one PING after the reverse path works again, not after give_up_s.
    """
    cfg = LinkConfig(rate_bps=1e5, segment_bytes=100, fin_linger_s=5.0, reoffer_s=60.0)
    data = _payload(1000, 1)
    tx, rx = _small_pair(cfg, data)
    t = 0.0
    while rx.progress[0] < 5:  # handshake and half the data, both ways clean
        t = _run(tx, rx, t, t + 0.01, 0.01)
    t = _run(tx, rx, t, t + 12.0, 0.01, drop_to_tx=True)  # every answer lost, linger ends
    assert rx.take_map() == (3, data)
    assert rx.state is ReceiverState.IDLE and not rx.closing
    assert [e.args["how"] for e in rx.events.pop_all() if e.name == "CLOSED"] == ["linger"]
    assert tx.state is SenderState.SENDING
    t_heal = t
    while tx.state is not SenderState.DONE and t < t_heal + 5.0:
        t = _run(tx, rx, t, t + 0.01, 0.01)
    assert tx.state is SenderState.DONE
    assert t - t_heal <= cfg.ping_period_s + 0.05
    assert [e.name for e in tx.events.pop_all()].count("DELIVERED") == 1


def test_sender_gives_up_the_close_after_close_tries() -> None:
    """Repeated FINs get at most ``close_tries`` FIN_ACKs, then an event and silence."""
    cfg = LinkConfig(rate_bps=1e5, close_tries=3)
    tx = LinkSender(cfg, session=2)
    tx.start(9, b"m" * 500, 0.0)
    fin = lp.encode(lp.Fin(2, 9, lp.FinStatus.VERIFIED))
    acks = 0
    for k in range(10):
        tx.receive(fin, float(k))
        out = [lp.decode(d) for d in tx.poll(float(k))]
        acks += sum(isinstance(p, lp.FinAck) for p in out)
    assert tx.state is SenderState.DONE and acks == 3
    names = [e.name for e in tx.events.pop_all()]
    assert names.count("DELIVERED") == 1 and names.count("CLOSE_GIVEN_UP") == 1
    assert tx.close_given_up and tx.next_deadline_s() is None


def test_receiver_close_ends_on_fin_ack_or_linger_and_waits_for_nothing_else() -> None:
    """COMPLETE lasts until FIN_ACK or fin_linger_s; then no deadline remains."""
    cfg = LinkConfig(rate_bps=1e5, segment_bytes=100, fin_linger_s=4.0)
    data = _payload(300, 2)
    rx = LinkReceiver(cfg)
    rx.receive(lp.encode(lp.Offer(5, 1, len(data), 100, hashlib.sha256(data).digest())), 0.0)
    for i in range(3):
        rx.receive(lp.encode(lp.Data(5, i, i, data[100 * i:100 * (i + 1)])), 0.1)
    assert rx.closing
    t, fins = 0.1, 0
    while rx.closing and t < 100.0:
        fins += sum(isinstance(lp.decode(d), lp.Fin) for d in rx.poll(t))
        if not rx.closing:
            break
        deadline = rx.next_deadline_s()
        assert deadline is not None and deadline <= 0.1 + cfg.fin_linger_s + 1e-9
        t = max(deadline, t)
    assert not rx.closing and 0.1 + cfg.fin_linger_s - 1e-9 <= t <= 0.1 + cfg.fin_linger_s + 1e-6
    assert fins == pytest.approx(cfg.fin_linger_s / cfg.status_period_s, abs=1)
    assert rx.next_deadline_s() is None
    # the same with a FIN_ACK: closed at once
    rx2 = LinkReceiver(cfg)
    rx2.receive(lp.encode(lp.Offer(6, 1, len(data), 100, hashlib.sha256(data).digest())), 0.0)
    for i in range(3):
        rx2.receive(lp.encode(lp.Data(6, i, i, data[100 * i:100 * (i + 1)])), 0.1)
    rx2.receive(lp.encode(lp.FinAck(6, 1)), 0.5)
    rx2.poll(0.5)  # the ACCEPT still owed goes out
    assert not rx2.closing and rx2.next_deadline_s() is None
    assert [e.args["how"] for e in rx2.events.pop_all() if e.name == "CLOSED"] == ["fin_ack"]


def test_delivered_sender_has_no_timer_left() -> None:
    """Once DONE and its FIN_ACK is out, the sender has no deadline (give_up_s included)."""
    cfg = LinkConfig(rate_bps=1e5, segment_bytes=100)
    data = _payload(700, 3)
    tx, rx = _small_pair(cfg, data)
    t = 0.0
    while tx.state is not SenderState.DONE and t < 10.0:
        t = _run(tx, rx, t, t + 0.01, 0.01)
    assert tx.state is SenderState.DONE
    tx.poll(t + 1.0)
    assert tx.next_deadline_s() is None


def test_every_sender_event_is_declared_by_the_radio_task() -> None:
    """The radio task forwards every LinkSender event; an undeclared one would raise in flight."""
    import inspect
    import re

    from fsw.comm import link_sender
    from fsw.tasks.radio_task import RadioTask

    emitted = set(re.findall(r'events\.emit\(\s*now_s,\s*"(\w+)"', inspect.getsource(link_sender)))
    assert {"DELIVERED", "CLOSE_GIVEN_UP", "LINK_LOST"} <= emitted
    declared = {e.name for e in RadioTask.EVENTS}
    assert emitted <= declared, emitted - declared
