"""One packet per ground-link activation (issue 15): the frames are joined in order into as
few packets as the port's size allows, and a MAVLink parser gets every frame back."""

from __future__ import annotations

import pytest

from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.comm.mavlink_downlink import coalesce


def _frames(n: int) -> list[bytes]:
    codec = new_codec(1, 1)
    return [codec.named_value_float_encode(i * 100, f"ch{i}".encode(), float(i)).pack(codec) for i in range(n)]


def test_frames_are_joined_in_order_within_the_packet_size() -> None:
    frames = _frames(9)
    size = len(frames[0])
    packets = coalesce(frames, 4 * size)
    assert [len(p) for p in packets] == [4 * size, 4 * size, size]
    assert b"".join(packets) == b"".join(frames)
    assert coalesce(frames, 10**6) == [b"".join(frames)]
    assert coalesce([], 100) == []


def test_a_frame_over_the_size_goes_alone() -> None:
    big, small = b"x" * 50, b"y" * 10
    assert coalesce([small, big, small, small], 30) == [small, big, small + small]


@pytest.mark.parametrize("n", [1, 7])
def test_a_parser_gets_every_frame_of_a_joined_datagram(n: int) -> None:
    frames = _frames(n)
    (packet,) = coalesce(frames, 65507)
    msgs = new_codec(255, 190).parse_buffer(packet) or []
    assert [m.get_type() for m in msgs] == ["NAMED_VALUE_FLOAT"] * n
    assert [m.value for m in msgs] == [float(i) for i in range(n)]
    assert all(isinstance(m, mavlink.MAVLink_named_value_float_message) for m in msgs)
