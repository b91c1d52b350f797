"""A link session survives either end restarting (issue 26, item 1), stepped clock.

The ideal time of a transfer is the map's bits over the capacity left after loss,
``8 x bytes / (rate x (1 - loss))``; a restarted end must not cost more than that again.
"""

from __future__ import annotations

import numpy as np
import pytest

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.link_sender import LinkSender, SenderState
from hil_sim.lab.link_sim import Restart, run_transfer
from hil_sim.link.radio_channel import RadioChannelConfig

LINK = LinkConfig()
CLEAN = RadioChannelConfig()
LOSSY = RadioChannelConfig(loss=0.3, ber=1e-5, duplicate=0.1, reorder=0.1)
DATA = np.random.default_rng(0).integers(0, 256, 24_000, dtype=np.uint8).tobytes()


def _ideal_s(ch: RadioChannelConfig) -> float:
    return 8.0 * len(DATA) / (LINK.rate_bps * (1.0 - ch.loss))


def _names(r, side: str) -> list[str]:
    return [e.name for s, e in r.events if s == side]


@pytest.mark.parametrize(("ch", "seed"), [(CLEAN, 0)] + [(LOSSY, s) for s in range(8)])
def test_receiver_restart_mid_transfer_delivers_within_twice_the_ideal_time(ch, seed):
    ideal = _ideal_s(ch)
    r = run_transfer(DATA, LINK, ch, seed=seed, restarts=[Restart("rx", 0.5 * ideal, 1.0)])
    assert r.delivered == DATA
    assert r.sender_state is SenderState.DONE
    assert r.delivered_s is not None and r.delivered_s <= 2.0 * ideal
    assert "UNKNOWN_SESSION" in _names(r, "rx")  # the new receiver answered the old session
    assert "REOFFERED" in _names(r, "tx")
    assert r.idle_steps == 0


@pytest.mark.parametrize("session", [None, 9])
@pytest.mark.parametrize("seed", range(4))
def test_sender_restart_mid_transfer_resumes_within_twice_the_ideal_time(seed, session):
    """The restarted sender offers the same map (same or new session); the receiver's STATUS
    says what it holds, so the transfer goes on from there."""
    ideal = _ideal_s(LOSSY)
    r = run_transfer(DATA, LINK, LOSSY, seed=seed, restarts=[Restart("tx", 0.5 * ideal, 1.0, session)])
    assert r.delivered == DATA
    assert r.sender_state is SenderState.DONE
    assert r.delivered_s is not None and r.delivered_s <= 2.0 * ideal
    assert "OFFER_ACCEPTED" in _names(r, "rx")
    assert _names(r, "rx").count("OFFER_ACCEPTED") == 1  # resumed, never started afresh


def test_both_ends_restart_one_after_the_other():
    ideal = _ideal_s(LOSSY)
    r = run_transfer(DATA, LINK, LOSSY, seed=3, restarts=[Restart("rx", 0.3 * ideal, 2.0),
                                                          Restart("tx", 0.6 * ideal, 2.0)])
    assert r.delivered == DATA and r.sender_state is SenderState.DONE
    assert r.delivered_s is not None and r.delivered_s <= 2.5 * ideal


def test_every_no_session_answer_lost_the_sender_reoffers_after_silence():
    """Without the NO_SESSION answers the sender still finds the restarted receiver: after
    ``reoffer_s`` without feedback an OFFER takes the place of a PING; the ACCEPT says the
    receiver holds nothing, and everything is sent again."""
    ideal = _ideal_s(CLEAN)

    def no_answers(side: str, d: bytes) -> bytes | None:
        return None if side == "a" and lp.packet_type(d) is lp.Ptype.NO_SESSION else d

    r = run_transfer(DATA, LINK, CLEAN, seed=0, tamper=no_answers, restarts=[Restart("rx", 0.5 * ideal, 1.0)])
    assert r.delivered == DATA and r.sender_state is SenderState.DONE
    reoffer = [e for s, e in r.events if s == "tx" and e.name == "REOFFERED"]
    assert len(reoffer) == 1 and reoffer[0].args["reason"].startswith("no answer for")
    stop_s = 0.5 * ideal
    assert reoffer[0].time_s <= stop_s + LINK.reoffer_s + LINK.ping_period_s + 0.5
    assert r.delivered_s is not None and r.delivered_s <= 2.0 * ideal + LINK.reoffer_s


def test_no_session_answers_are_rate_limited_and_reported_once():
    cfg = LinkConfig(rate_bps=1e6)
    rx = LinkReceiver(cfg)
    out: list[bytes] = []
    t = 0.0
    for i in range(1000):  # 1000 DATA of an unknown session in one second
        t = i * 1e-3
        rx.receive(lp.encode(lp.Data(5, i % 7, i, b"x" * 10)), t)
        out += rx.poll(t)
    kinds = [lp.decode(d) for d in out]
    assert all(isinstance(k, lp.NoSession) and k.session == 5 for k in kinds)
    assert 1 <= len(kinds) <= 1.0 / cfg.min_status_interval_s + 1
    assert [e.name for e in rx.events.pop_all()] == ["UNKNOWN_SESSION"]


def test_a_stale_no_session_does_not_disturb_a_new_session():
    """A NO_SESSION for the session the sender left behind (re-offer) is ignored."""
    cfg = LinkConfig(rate_bps=1e6)
    tx = LinkSender(cfg, session=4)
    tx.start(1, b"m" * 2000, 0.0)
    tx.poll(0.0)
    tx.receive(lp.encode(lp.Accept(4, 1)), 0.01)
    tx.poll(0.02)
    tx.receive(lp.encode(lp.NoSession(4)), 0.03)  # the receiver restarted
    assert tx.state is SenderState.OFFERING and tx.session == 5
    tx.receive(lp.encode(lp.NoSession(4)), 0.04)  # a late copy of the same answer
    assert tx.state is SenderState.OFFERING and tx.session == 5 and tx.stats.reoffers == 1
    (offer,) = [lp.decode(d) for d in tx.poll(0.05)]
    assert isinstance(offer, lp.Offer) and offer.session == 5


def test_an_offer_of_a_map_delivered_before_is_confirmed_not_sent_again():
    """A sender that restarted after the receiver verified the map (its FIN lost) is told
    at once: the OFFER of the same map under any session gets FIN(VERIFIED)."""
    cfg = LinkConfig(rate_bps=1e6, segment_bytes=100, fin_linger_s=1.0)
    data = DATA[:1000]
    r = run_transfer(data, cfg, CLEAN, seed=0, close=True)
    assert r.delivered == data
    rx = LinkReceiver(cfg)
    tx = LinkSender(cfg, session=1)
    tx.start(1, data, 0.0)
    t = 0.0
    while rx.take_map() is None:
        for d in tx.poll(t):
            rx.receive(d, t)
        for d in rx.poll(t):
            tx.receive(d, t)
        t += 0.01
    t += 5.0  # the linger is long over
    tx2 = LinkSender(cfg, session=2)
    tx2.start(1, data, t)
    for _ in range(5):
        for d in tx2.poll(t):
            rx.receive(d, t)
        for d in rx.poll(t):
            tx2.receive(d, t)
        t += 0.01
    assert tx2.state is SenderState.DONE and tx2.stats.data_sent == 0
    assert rx.take_map() is None  # not delivered twice
