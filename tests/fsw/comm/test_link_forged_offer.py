"""A forged OFFER (valid CRC-32, wrong parameters) does not stall a map transfer, stepped clock.

A corruption that passes CRC-32 in an OFFER makes the receiver hold the session with the
wrong size, segment size or SHA-256. The receiver drops a session whose data cannot be the
map it holds: ``misfit_limit`` DATA in a row that do not fit it, or a second hash mismatch in
it. Its NO_SESSION makes the sender offer again under a new session (the restart path), and
the new OFFER carries the right parameters (docs/link.md, "Limits").
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from collections.abc import Callable

import numpy as np
import pytest

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver, ReceiverState
from fsw.comm.link_sender import LinkSender, SenderState
from fsw.framework.params import ConfigError, build
from hil_sim.lab.link_sim import run_transfer
from hil_sim.link.radio_channel import RadioChannelConfig

CFG = LinkConfig()  # the flight rate and segment size
N_SEG = 20
DATA = np.random.default_rng(7).integers(0, 256, N_SEG * CFG.segment_bytes - 100, dtype=np.uint8).tobytes()
PASS_S = N_SEG * (CFG.segment_bytes + lp.DATA_OVERHEAD) * 8 / CFG.rate_bps  # one pass of the map
STEP_S = 0.01


def _forge(d: bytes, **change: object) -> bytes:
    """The OFFER ``d`` with fields changed and its CRC-32 made valid again (what CRC-32 cannot see)."""
    o = lp.decode(d)
    assert isinstance(o, lp.Offer)
    fields = {"session": o.session, "map_id": o.map_id, "size": o.size,
              "segment_bytes": o.segment_bytes, "sha256": o.sha256} | change
    forged = lp.encode(lp.Offer(**fields))  # type: ignore[arg-type]
    head = forged[:-4]
    assert struct.unpack("<I", forged[-4:])[0] == zlib.crc32(head)
    return forged


def _run(tamper: Callable[[bytes, float], list[bytes]], t_max_s: float,
         cfg: LinkConfig = CFG) -> tuple[LinkSender, LinkReceiver, float, bytes | None]:
    """Sender and receiver in lockstep on a loss-free channel; ``tamper`` rewrites what goes
    to the receiver. Returns when the map is delivered and the sender is DONE, or at ``t_max_s``."""
    tx, rx = LinkSender(cfg, session=5), LinkReceiver(cfg)
    tx.start(3, DATA, 0.0)
    got: bytes | None = None
    t = 0.0
    while t < t_max_s:
        for d in tx.poll(t):
            for d2 in tamper(d, t):
                rx.receive(d2, t)
        for d in rx.poll(t):
            tx.receive(d, t)
        m = rx.take_map()
        if m is not None:
            assert m == (3, DATA), "the receiver accepted a map that was not sent"
            got = m[1]
        if got is not None and tx.state is SenderState.DONE:
            break
        if tx.finished and tx.state is not SenderState.DONE:
            break
        t += STEP_S
    return tx, rx, t, got


def _names(end: LinkSender | LinkReceiver) -> list[str]:
    return [e.name for e in end.events.pop_all()]


@pytest.mark.parametrize("change", [
    {"size": len(DATA) + 300},  # one segment more: the last one is too short for it
    {"size": len(DATA) - 1},  # the last segment one byte too long
    {"segment_bytes": CFG.segment_bytes // 2},  # every full segment misfits
])
def test_a_forged_offer_accepted_first_does_not_stall_the_transfer(change):
    """The receiver takes a forged OFFER (wrong size or segment size) in place of the sender's,
    answers ACCEPT, and every DATA the sender then streams misfits. Before the receiver dropped
    such a session the transfer never completed (the sender streamed until an operator aborted
    it); now ``misfit_limit`` misfits drop it, NO_SESSION brings a new OFFER, the map arrives."""
    forged: list[float] = []

    def tamper(d: bytes, t: float) -> list[bytes]:
        if lp.packet_type(d) is lp.Ptype.OFFER and not forged:
            forged.append(t)
            return [_forge(d, **change)]
        return [d]

    tx, rx, t, got = _run(tamper, t_max_s=120.0)
    assert forged == [0.0]
    assert got == DATA and hashlib.sha256(got).digest() == hashlib.sha256(DATA).digest()
    assert tx.state is SenderState.DONE
    assert t <= 3.0 * PASS_S  # the first pass, a few misfits, a round trip, the second pass
    rx_names, tx_names = _names(rx), _names(tx)
    assert rx_names.count("SESSION_DROPPED") == 1 and "MAP_VERIFIED" in rx_names
    assert tx_names.count("REOFFERED") == 1 and tx.session == 6


def _mid_transfer(**change: object) -> Callable[[bytes, float], list[bytes]]:
    """A tamper that slips a forged OFFER of the running session (its fields ``change``d) in
    before the DATA half-way through the first pass."""
    sent: list[float] = []

    def tamper(d: bytes, t: float) -> list[bytes]:
        if lp.packet_type(d) is lp.Ptype.DATA:
            sent.append(t)
            if len(sent) == N_SEG // 2:
                offer = lp.encode(lp.Offer(5, 3, len(DATA), CFG.segment_bytes, hashlib.sha256(DATA).digest()))
                return [_forge(offer, **change), d]
        return [d]
    return tamper


def test_a_forged_offer_mid_transfer_does_not_stall_the_transfer():
    """A forged OFFER of the running session with another segment size resets the receiver to
    it half-way through; the transfer recovers by itself and the map arrives bit-exact."""
    tx, rx, t, got = _run(_mid_transfer(segment_bytes=CFG.segment_bytes + 8), t_max_s=120.0)
    assert got == DATA and tx.state is SenderState.DONE
    assert t <= 3.5 * PASS_S
    assert "SESSION_DROPPED" in _names(rx)


def test_a_forged_offer_too_large_mid_transfer_does_not_end_the_transfer_rejected():
    """A forged OFFER of the running session above ``max_map_bytes`` is refused by the receiver;
    its REJECT reaches a sender that has no OFFER out (its own was accepted): it offers again
    instead of ending REJECTED, and the map arrives bit-exact."""
    tx, rx, t, got = _run(_mid_transfer(size=CFG.max_map_bytes + 1), t_max_s=120.0)
    assert got == DATA and tx.state is SenderState.DONE
    assert t <= 3.5 * PASS_S
    assert "OFFER_REJECTED" in _names(rx) and "REOFFERED" in _names(tx)


def test_a_reject_of_its_own_offer_still_ends_the_transfer_rejected():
    """A map over the receiver's ``max_map_bytes``: the REJECT answers the sender's own OFFER."""
    small = LinkConfig(max_map_bytes=N_SEG * CFG.segment_bytes // 2)
    tx, rx = LinkSender(CFG, session=5), LinkReceiver(small)
    tx.start(3, DATA, 0.0)
    t = 0.0
    while t < 10.0 and not tx.finished:
        for d in tx.poll(t):
            rx.receive(d, t)
        for d in rx.poll(t):
            tx.receive(d, t)
        t += STEP_S
    assert tx.state is SenderState.REJECTED and "REOFFERED" not in _names(tx)


def test_a_forged_offer_with_a_wrong_sha256_does_not_fail_the_transfer():
    """A forged SHA-256 fits every DATA: each pass ends in a hash mismatch. The first is the
    usual resend (FIN(HASH_MISMATCH)); the second in the same session drops it, and the new
    OFFER carries the right SHA-256. Before, the sender gave up after ``max_restarts``."""
    forged: list[float] = []

    def tamper(d: bytes, t: float) -> list[bytes]:
        if lp.packet_type(d) is lp.Ptype.OFFER and not forged:
            forged.append(t)
            return [_forge(d, sha256=bytes(32))]
        return [d]

    tx, rx, t, got = _run(tamper, t_max_s=120.0)
    assert got == DATA and tx.state is SenderState.DONE
    assert t <= 3.5 * PASS_S
    rx_names = _names(rx)
    assert rx_names.count("HASH_MISMATCH") == 2 and rx_names.count("SESSION_DROPPED") == 1
    assert [e for e in _names(tx) if e.startswith("HASH_MISMATCH")] == ["HASH_MISMATCH_RESEND"]


LOSSY = RadioChannelConfig(loss=0.3, ber=1e-5, duplicate=0.1, reorder=0.1)


@pytest.mark.parametrize(("change", "bound"), [({"size": len(DATA) + 300}, 3.5),
                                               ({"segment_bytes": CFG.segment_bytes + 8}, 3.5),
                                               ({"sha256": bytes(32)}, 5.0)])
@pytest.mark.parametrize("seed", range(4))
def test_a_forged_offer_on_a_lossy_channel_is_recovered_from(change, bound, seed):
    """The same over the channel model (30 % loss, BER 1e-5, duplication, reordering): the
    first OFFER to reach the receiver is forged; the map arrives bit-exact within ``bound``
    times the ideal time of one transfer, and no deadline of either end wakes it for nothing."""
    forged: list[bytes] = []

    def tamper(side: str, d: bytes) -> bytes | None:
        if side == "b" and lp.packet_type(d) is lp.Ptype.OFFER and not forged:
            try:
                lp.decode(d)
            except lp.PacketError:
                return d  # a bit error: CRC-32 refuses it anyway
            forged.append(d)
            return _forge(d, **change)
        return d

    r = run_transfer(DATA, CFG, LOSSY, seed=seed, tamper=tamper, t_max_s=600.0)
    ideal_s = 8.0 * len(DATA) / (CFG.rate_bps * (1.0 - LOSSY.loss))
    assert forged and r.delivered == DATA and r.sender_state is SenderState.DONE
    assert r.delivered_s is not None and r.delivered_s <= bound * ideal_s
    assert r.idle_steps == 0


def _receiving(cfg: LinkConfig) -> LinkReceiver:
    rx = LinkReceiver(cfg)
    rx.receive(lp.encode(lp.Offer(4, 1, 1000, 100, hashlib.sha256(DATA[:1000]).digest())), 0.0)
    rx.poll(0.0)
    return rx


def test_misfits_drop_the_session_only_when_misfit_limit_come_in_a_row():
    """Stale DATA of another map under the same session number (fewer than ``misfit_limit``
    in a row) leave the session alone; ``misfit_limit`` in a row drop it with one event and a
    NO_SESSION answer; later DATA of it get NO_SESSION (rate-limited), never a traceback."""
    cfg = LinkConfig(rate_bps=1e6, misfit_limit=4)
    rx = _receiving(cfg)
    t = 0.1
    for rounds in range(3):  # three misfits, then one that fits: the count starts again
        for i in range(3):
            rx.receive(lp.encode(lp.Data(4, 20 + i, i, b"x" * 100)), t)  # beyond the map
        rx.receive(lp.encode(lp.Data(4, rounds, 9, DATA[rounds * 100:(rounds + 1) * 100])), t)
        t += 0.01
    assert rx.state is ReceiverState.RECEIVING and rx.progress == (3, 10)
    assert all(isinstance(lp.decode(d), lp.Status) for d in rx.poll(t))
    for i in range(4):
        rx.receive(lp.encode(lp.Data(4, 3, 10 + i, b"y" * 50)), t)  # wrong length
    assert rx.state is ReceiverState.IDLE and rx.progress == (0, 0)
    assert [lp.decode(d) for d in rx.poll(t)] == [lp.NoSession(4)]
    names = [e.name for e in rx.events.pop_all()]
    assert names == ["OFFER_ACCEPTED", "SESSION_DROPPED"]
    rx.receive(lp.encode(lp.Data(4, 4, 20, DATA[400:500])), t + 0.5)
    assert [lp.decode(d) for d in rx.poll(t + 0.5)] == [lp.NoSession(4)]
    assert rx.stats.foreign_packets == 3 * 3 + 4 + 1


def test_misfit_limit_is_a_link_parameter():
    assert LinkConfig().misfit_limit == 8
    assert build(LinkConfig, {"misfit_limit": 3}).misfit_limit == 3
    with pytest.raises(ConfigError):
        build(LinkConfig, {"misfit_limit": 0})
