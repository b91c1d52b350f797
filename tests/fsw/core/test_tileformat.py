"""The compact tile format of the map sync (fsw.core.codec.tileformat, mapcodec.encode_tile)."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from fsw.core.codec.mapcodec import CodecConfig, MapCodecError, decode_tile, encode_map, encode_tile, tile_profile
from fsw.core.codec.tileformat import profile_from_bytes

CFG = CodecConfig()
PROFILE = tile_profile(CFG, cell_m=0.03, wheel_diameter_m=0.12, frame=0, shape=(40, 56), origin=(-0.6, 1.2),
                       tile_cells=16)


def tiles(seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for k, shape in enumerate([(16, 16), (16, 8), (8, 16), (1, 1), (16, 16), (16, 16)]):
        yy, xx = np.mgrid[: shape[0], : shape[1]].astype(float)
        z = (0.4 * np.sin(yy / 3.0) + 0.3 * np.cos(xx / 4.0) + rng.normal(0, 0.02, shape) + 3.0 * k - 4.0)
        z = z.astype(np.float32)
        if k in (1, 4):
            z[rng.random(shape) < 0.4] = np.nan
        if k == 5:
            z[:] = np.nan
        out.append(z)
    return out


def test_tiles_round_trip_within_the_bound_and_are_smaller_than_containers() -> None:
    for z in tiles():
        blob = encode_tile(z, PROFILE, CFG)
        back = decode_tile(blob, PROFILE, z.shape)
        known = np.isfinite(z)
        assert np.array_equal(np.isfinite(back), known)
        if known.any():
            assert float(np.max(np.abs(back[known] - z[known]))) <= PROFILE.error_bound_m
        full = encode_map(z, cell_m=0.03, wheel_diameter_m=0.12, cfg=CFG).data
        assert len(blob) <= len(full) - 80  # the container's 112-byte header is not repeated
        assert decode_tile(blob, PROFILE, z.shape).tobytes() == back.tobytes()  # decodes alone, the same


def test_profile_bytes_round_trip_and_name_frame_grid_and_codec() -> None:
    assert profile_from_bytes(PROFILE.to_bytes()) == PROFILE
    others = [tile_profile(CFG, cell_m=0.03, wheel_diameter_m=0.12, frame=1, shape=(40, 56), origin=(-0.6, 1.2),
                           tile_cells=16),
              tile_profile(CFG, cell_m=0.03, wheel_diameter_m=0.12, frame=0, shape=(40, 56), origin=(-0.6, 1.5),
                           tile_cells=16),
              tile_profile(CodecConfig(error_bound_wheels=0.5), cell_m=0.03, wheel_diameter_m=0.12, frame=0,
                           shape=(40, 56), origin=(-0.6, 1.2), tile_cells=16)]
    assert len({PROFILE.pid, *(o.pid for o in others)}) == 4
    assert not PROFILE.same_grid(others[0]) and not PROFILE.same_grid(others[1]) and PROFILE.same_grid(others[2])
    with pytest.raises(MapCodecError):
        profile_from_bytes(PROFILE.to_bytes()[:-1])
    bad = bytearray(PROFILE.to_bytes())
    bad[0] = 9
    with pytest.raises(MapCodecError, match="version"):
        profile_from_bytes(bytes(bad))


def test_a_corrupt_tile_body_is_a_codec_error_or_a_tile_of_its_shape() -> None:
    rng = np.random.default_rng(3)
    for z in tiles(1)[:2]:
        blob = encode_tile(z, PROFILE, CFG)
        for n in range(len(blob)):
            with contextlib.suppress(MapCodecError):
                assert decode_tile(blob[:n], PROFILE, z.shape).shape == z.shape
        for _ in range(300):
            bad = bytearray(blob)
            bad[int(rng.integers(0, len(bad)))] = int(rng.integers(0, 256))
            with contextlib.suppress(MapCodecError), np.errstate(over="ignore", invalid="ignore"):
                assert decode_tile(bytes(bad), PROFILE, z.shape).shape == z.shape
    with pytest.raises(MapCodecError, match="tile"):
        decode_tile(encode_tile(tiles()[0], PROFILE, CFG), PROFILE, (17, 16))
