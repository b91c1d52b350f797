"""The parameters and the counters of one end of the two-way map sync (docs/sync.md).

:class:`SyncConfig` is the ``[map_sync]`` section of both flight programs; :class:`SyncStats`
counts what an end (:class:`fsw.comm.team.map_sync.MapSync`) published, put on the air and took
in, the figures ``safer-hil experiment sync`` reports.
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.framework.params import param


@dataclass(frozen=True)
class SyncConfig:
    """Two-way map sync parameters (docs/sync.md; ``[map_sync]`` in the flight files)."""

    enabled: bool = param(False, doc="the agent's radio task runs a sync end (both agents of a team; "
                                     "docs/sync.md, \"In flight\")")
    rate_bps: float = param(9600.0, lo=300.0, hi=1e8, units="bit/s", doc="pacing of every packet")
    pacing_catchup_s: float = param(0.05, lo=0.0, hi=1.0, units="s")
    tile_cells: int = param(16, lo=4, hi=256, units="cells", doc="tile side")
    mtu_bytes: int = param(512, lo=128, hi=8192, units="B", doc="largest datagram")
    ack_delay_s: float = param(0.3, lo=0.0, hi=30.0, units="s", doc="DIGEST this long after new tiles")
    min_digest_interval_s: float = param(0.5, lo=0.0, hi=60.0, units="s",
                                         doc="DIGESTs at most this often (answers excepted)")
    keepalive_s: float = param(10.0, lo=0.5, hi=600.0, units="s", doc="DIGEST at least this often")
    probe_s: float = param(0.8, lo=0.05, hi=60.0, units="s",
                           doc="after the last tile: a DIGEST asking for an answer; doubles")
    probe_max_s: float = param(1.0, lo=0.1, hi=600.0, units="s", doc="longest probe interval")
    reorder_slack_s: float = param(0.5, lo=0.0, hi=60.0, units="s",
                                   doc="a tile is lost once one sent this much later arrived")
    stall_s: float = param(25.0, lo=0.5, hi=600.0, units="s", doc="no packet this long: tiles pause")
    holdings_retry_s: float = param(1.5, lo=0.1, hi=600.0, units="s",
                                    doc="HOLDINGS asked for or sent again at most this often")


@dataclass
class SyncStats:
    rounds: int = 0
    tiles_published: int = 0
    minimal_bytes: int = 0  # TILE packet bytes of every published version, once; a fresh end's profile once
    packets_out: int = 0
    bytes_out: int = 0  # everything put on the air
    tiles_out: int = 0
    tile_bytes_out: int = 0  # of bytes_out: TILEs (the own layer's and tiles given back)
    tile_body_bytes_out: int = 0  # of which the tile bodies (the rest: packet headers)
    resent_bytes_out: int = 0  # of tile_bytes_out: the entries of versions sent again
    holdings_bytes_out: int = 0
    profiles_out: int = 0  # DIGESTs that carried my tile profile
    profile_bytes_out: int = 0  # of digest_bytes_out: the profiles they carried
    resent_tiles: int = 0  # a version sent again (proved lost)
    returns_out: int = 0  # the peer's own tiles given back to it
    digests_out: int = 0
    digests_answer: int = 0  # of which answers to a probe
    digests_probe: int = 0  # of which probes (tiles in flight unacknowledged, or the link silent)
    digest_bytes_out: int = 0
    holdings_out: int = 0
    packets_in: int = 0
    bytes_in: int = 0  # valid packets received, channel duplicates excepted
    digest_bytes_in: int = 0  # of which DIGESTs
    holdings_bytes_in: int = 0  # of which HOLDINGS
    stale_bytes_in: int = 0  # of which the entries of tiles of a version already held
    dup_packets: int = 0
    bad_packets: int = 0
    foreign_packets: int = 0
    unknown_profile_tiles: int = 0  # TILEs naming a tile profile not (yet) known: dropped
    profile_mismatches: int = 0  # profiles of another frame or grid refused, and the TILEs naming them
    tiles_in: int = 0
    stale_tiles: int = 0  # a version already held or older
    adopted: int = 0  # own tiles given back by the peer after a restart
    full_resends: int = 0
    peer_restarts: int = 0
    oversize_tiles: int = 0
    nonfinite_cells: int = 0
