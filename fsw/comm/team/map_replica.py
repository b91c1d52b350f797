"""One agent's replica of the shared map (docs/sync.md): tiles, versions, hashes.

The shared map is two layers of square tiles (``tile_cells`` a side, on the map grid): the
agent's own layer, which only it writes, and its copy of the peer's layer. Each layer tile
is a tile body in the compact tile format (``fsw.core.codec.tileformat``: the map codec's
quadtree reduction within the wheel-diameter error bound, without the container header) of
its owner's tile profile, versioned by its owner's counter. Both replicas hold the same
bytes of every tile, so the same content; :meth:`MapReplica.replica_hash` hashes the decoded
tiles of both layers. What travels, and when, is the protocol's business
(:mod:`fsw.comm.team.map_sync`); this module only keeps the tiles and says what changed.
"""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team import sync_packets as sp
from fsw.core.codec.mapcodec import (
    CodecConfig,
    MapCodecError,
    TileProfile,
    decode_tile,
    encode_tile,
    tile_profile,
)

F32 = NDArray[np.float32]


@dataclass
class TileRec:
    version: int
    digest: int
    blob: bytes
    z: F32


def _canonical(z: F32) -> bytes:
    return np.where(np.isfinite(z), z, np.float32(np.nan)).astype(np.float32).tobytes()


class MapReplica:
    """Both layers of one agent's replica: ``own`` (its tiles) and ``held`` (its copy of the peer's)."""

    def __init__(self, agent: int, peer: int, shape: tuple[int, int], tile_cells: int, cell_m: float,
                 wheel_diameter_m: float, codec: CodecConfig | None = None, *, frame: int = 0,
                 origin: tuple[float, float] = (0.0, 0.0)) -> None:
        self.agent, self.peer = agent, peer
        self.shape = (int(shape[0]), int(shape[1]))
        self.tile_cells = tile_cells
        self.cell_m, self.wheel_m = cell_m, wheel_diameter_m
        self.codec = codec or CodecConfig()
        self.bound_m = self.codec.error_bound_wheels * wheel_diameter_m
        self.profile = tile_profile(self.codec, cell_m=cell_m, wheel_diameter_m=wheel_diameter_m, frame=frame,
                                    shape=self.shape, origin=origin, tile_cells=tile_cells)
        self.nty, self.ntx = -(-self.shape[0] // tile_cells), -(-self.shape[1] // tile_cells)
        self.own: dict[int, TileRec] = {}
        self.held: dict[int, TileRec] = {}
        self.counter = 0  # the last version this agent gave one of its tiles
        self.source: dict[int, F32] = {}  # own tiles: the map each version was made from
        self._hash_cache: dict[int, bytes] = {}
        self._replica_hash: str | None = None

    @property
    def n_tiles(self) -> int:
        return self.nty * self.ntx

    def tile_slice(self, t: int) -> tuple[slice[int, int, None], slice[int, int, None]]:
        ty, tx = divmod(t, self.ntx)
        tc = self.tile_cells
        return slice(ty * tc, min((ty + 1) * tc, self.shape[0])), slice(tx * tc, min((tx + 1) * tc, self.shape[1]))

    def layer(self, owner: int) -> dict[int, TileRec]:
        return self.own if owner == self.agent else self.held

    def layer_hash(self, owner: int) -> bytes:
        """A hash of a layer's (tile, digest) pairs (what DIGESTs compare; ``HASH_BYTES`` bytes)."""
        if owner not in self._hash_cache:
            h = hashlib.blake2b(digest_size=sp.HASH_BYTES)
            for t, rec in sorted(self.layer(owner).items()):
                h.update(t.to_bytes(2, "little") + rec.digest.to_bytes(4, "little"))
            self._hash_cache[owner] = h.digest()
        return self._hash_cache[owner]

    def replica_hash(self) -> str:
        """Hash of the decoded content of both layers (owner, tile, cells): equal replicas,
        equal hashes."""
        if self._replica_hash is None:
            h = hashlib.blake2b(digest_size=16)
            for owner in sorted((self.agent, self.peer)):
                for t, rec in sorted(self.layer(owner).items()):
                    h.update(bytes([owner]) + t.to_bytes(2, "little") + _canonical(rec.z))
            self._replica_hash = h.hexdigest()
        return self._replica_hash

    def replica_map(self, owner: int) -> F32:
        """One layer painted on the map grid (NaN where it holds nothing)."""
        z = np.full(self.shape, np.nan, np.float32)
        for t, rec in self.layer(owner).items():
            z[self.tile_slice(t)] = rec.z
        return z

    def fused_map(self) -> F32:
        """The team's map from both layers: the mean where both know a cell, else the one that does."""
        a, b = self.replica_map(self.agent), self.replica_map(self.peer)
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(a) & np.isfinite(b), 0.5 * (a + b), np.where(np.isfinite(a), a, b))

    def touch(self, owner: int) -> None:
        """A layer changed: its hashes are stale."""
        self._hash_cache.pop(owner, None)
        self._replica_hash = None

    # ---------------------------------------------------------------- own tiles
    def changed(self, t: int, sub: F32) -> bool:
        """Whether tile ``t`` of the agent's map (``sub``) differs from what its last version was
        made from: a cell became known or unknown, or moved by more than the error bound."""
        known = np.isfinite(sub)
        rec = self.own.get(t)
        if rec is None:
            return bool(known.any())
        src = self.source.get(t, rec.z)
        was = np.isfinite(src)
        return bool((known != was).any()) or bool(
            known.any() and float(np.max(np.abs(sub[known] - src[known]))) > self.bound_m)

    def encode(self, sub: F32) -> bytes:
        """A tile's body in the compact tile format of the agent's profile."""
        return encode_tile(sub, self.profile, self.codec)

    def new_version(self, t: int, blob: bytes, sub: F32) -> TileRec:
        """Tile ``t`` of the own layer becomes ``blob`` (made from ``sub``) under the next version."""
        self.counter += 1
        rec = TileRec(self.counter, sp.blob_digest(blob), blob, decode_tile(blob, self.profile, sub.shape))
        self.own[t] = rec
        self.source[t] = np.array(sub, np.float32)
        self.touch(self.agent)
        return rec

    def decode_tile(self, t: int, blob: bytes, profile: TileProfile) -> F32 | None:
        """The cells of a received tile of ``profile`` (its grid this replica's), or None when
        the blob is not a valid tile ``t``."""
        if t >= self.n_tiles:
            return None
        ys, xs = self.tile_slice(t)
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                z = decode_tile(blob, profile, (ys.stop - ys.start, xs.stop - xs.start))
        except (MapCodecError, ValueError, MemoryError):
            return None
        if z.shape != (ys.stop - ys.start, xs.stop - xs.start) or np.isinf(z).any():
            return None
        return z

    # ---------------------------------------------------------------- checkpoint
    def layers_state(self) -> dict[str, dict[str, list[int | str]] | dict[str, str]]:
        """Both layers (version, base64 tile body per tile) and the own tiles' sources, for a
        JSON checkpoint (``fsw.comm.team.sync_checkpoint.save``)."""
        def layer(d: dict[int, TileRec]) -> dict[str, list[int | str]]:
            return {str(t): [r.version, base64.b64encode(r.blob).decode()] for t, r in d.items()}
        return {"own": layer(self.own), "held": layer(self.held),
                "source": {str(t): base64.b64encode(z.tobytes()).decode() for t, z in self.source.items()}}

    def load_layers(self, own: Mapping[str, Sequence[int | str]], held: Mapping[str, Sequence[int | str]],
                    source: Mapping[str, str], peer_profile: TileProfile | None) -> None:
        """The layers and sources of :meth:`layers_state`, the held layer's tiles of
        ``peer_profile`` (raises ``KeyError``, ``TypeError``, ``ValueError`` or
        ``MapCodecError`` on a malformed state)."""
        if held and peer_profile is None:
            raise ValueError("the held layer has tiles but the state has no peer tile profile")
        for layer, d, prof in ((own, self.own, self.profile), (held, self.held, peer_profile)):
            for key, (ver, b64) in layer.items():
                if not isinstance(b64, str):
                    raise TypeError(f"tile {key}: its body is not base64 text")
                blob = base64.b64decode(b64)
                t = int(key)
                if not 0 <= t < self.n_tiles or prof is None:
                    raise ValueError(f"tile {key} is not a tile of the map")
                ys, xs = self.tile_slice(t)
                z = decode_tile(blob, prof, (ys.stop - ys.start, xs.stop - xs.start))
                d[t] = TileRec(int(ver), sp.blob_digest(blob), blob, z)
        for key, b64s in source.items():
            t = int(key)
            ys, xs = self.tile_slice(t)
            self.source[t] = np.frombuffer(base64.b64decode(b64s), np.float32).reshape(
                ys.stop - ys.start, xs.stop - xs.start).copy()
        self.touch(self.agent)
        self.touch(self.peer)
