"""The Cliff-bot on the bench: receive the map, verify it, decode it, report (ALGORITHM.md §6.6).

:class:`Cliffbot` runs the flight :class:`~fsw.comm.link_receiver.LinkReceiver` over any
``RadioPort`` (the simulated channel, UDP, a serial modem). For every map the link
accepts (whole-map SHA-256 already checked by the link) it decodes the container, checks
the decoded map against the original when it knows it, and returns a
:class:`CliffbotReport`; :func:`write_figure13` draws the paper's Figure 13 (original beside
received, lighter = higher).

As a separate process (for the UDP bench)::

    python -m hil_sim.cliffbot_receiver --listen udp://127.0.0.1:47600 --out out/cliffbot \\
        [--original map.npy] [--count 1] [--timeout 120]

prints one JSON report per map and exits 0 when ``--count`` maps arrived (1 on timeout).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver
from fsw.core.mapcodec import MapCodecError, decode_map
from fsw.drivers.radio import RadioPort, open_radio


@dataclass(frozen=True)
class CliffbotReport:
    map_id: int
    container_bytes: int
    decoded: bool
    error: str
    shape: tuple[int, int]
    known_cells: int
    bound_m: float
    max_error_m: float | None  # against the original, if known
    unknown_preserved: bool | None
    png: str


class Cliffbot:
    """Receiver, decoder and reporter; ``step(now_s)`` pumps the radio once."""

    def __init__(self, link: LinkConfig, port: RadioPort, out_dir: Path | None = None,
                 originals: dict[int, NDArray[np.float32]] | None = None) -> None:
        self.rx = LinkReceiver(link)
        self.port = port
        self.out_dir = out_dir
        self.originals = originals or {}
        self.reports: list[CliffbotReport] = []
        self.maps: dict[int, NDArray[np.float32]] = {}

    def step(self, now_s: float, timeout_s: float = 0.0) -> list[CliffbotReport]:
        d = self.port.recv(timeout_s, now_s)
        while d is not None:
            self.rx.receive(d, now_s)
            d = self.port.recv(0.0, now_s)
        for pkt in self.rx.poll(now_s):
            self.port.send(pkt, now_s)
        new = []
        got = self.rx.take_map()
        while got is not None:
            new.append(self._report(*got))
            got = self.rx.take_map()
        self.reports += new
        return new

    def _report(self, map_id: int, data: bytes) -> CliffbotReport:
        try:
            dec = decode_map(data)
        except MapCodecError as exc:
            return CliffbotReport(map_id, len(data), False, str(exc), (0, 0), 0, 0.0, None, None, "")
        z = dec.z
        self.maps[map_id] = z
        orig = self.originals.get(map_id)
        max_err = unknown_ok = None
        png = ""
        if orig is not None and orig.shape == z.shape:
            k = np.isfinite(orig)
            max_err = float(np.abs(z[k].astype(np.float64) - orig[k]).max()) if k.any() else 0.0
            unknown_ok = bool(np.array_equal(np.isnan(z), ~k))
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            path = self.out_dir / f"cliffbot_map_{map_id}.png"
            write_figure13(orig if orig is not None else z, z, path,
                           f"map {map_id}: {len(data)} bytes, bound {dec.header.error_bound_m:.3f} m")
            np.save(self.out_dir / f"cliffbot_map_{map_id}.npy", z)
            png = str(path)
        return CliffbotReport(map_id, len(data), True, "", z.shape, int(np.isfinite(z).sum()),
                              dec.header.error_bound_m, max_err, unknown_ok, png)


def write_figure13(original: NDArray[np.floating], received: NDArray[np.floating], path: Path,
                   title: str = "") -> None:
    """Paper Figure 13: grayscale elevation, original (left) and transmitted (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    both = np.concatenate([original[np.isfinite(original)], received[np.isfinite(received)]])
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.2))
    cmap = matplotlib.colormaps["gray"].with_extremes(bad="#c03030")
    for ax, img, name in zip(axes, (original, received), ("original", "received by the Cliff-bot"),
                             strict=True):
        im = ax.imshow(img, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8, label="elevation [m] (red: unknown)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil_sim.cliffbot_receiver",
                                description="Bench Cliff-bot: receive maps over a radio, verify, "
                                "decode, report (one JSON line per map) and draw Figure 13.")
    p.add_argument("--listen", required=True, help="radio URL, e.g. udp://127.0.0.1:47600")
    p.add_argument("--peer", default="", help="udp: the RECON-bot's udp://HOST:PORT")
    p.add_argument("--out", type=Path, default=Path("out/cliffbot"), help="PNG/npy directory")
    p.add_argument("--original", type=Path, help=".npy original map (for the error check)")
    p.add_argument("--map-id", type=int, default=1, help="map id the original belongs to")
    p.add_argument("--count", type=int, default=1, help="exit after this many maps")
    p.add_argument("--timeout", type=float, default=120.0, help="give up after this many seconds")
    p.add_argument("--rate-bps", type=float, default=LinkConfig().rate_bps, help="radio bit rate")
    args = p.parse_args(argv)
    originals = {}
    if args.original is not None:
        try:
            originals[args.map_id] = np.load(args.original, allow_pickle=False).astype(np.float32)
        except (OSError, ValueError) as exc:
            print(f"cliffbot: error: {args.original}: {exc}", file=sys.stderr)
            return 2
    try:
        port = open_radio(args.listen, args.peer)
    except (ValueError, OSError) as exc:
        print(f"cliffbot: error: {exc}", file=sys.stderr)
        return 2
    bot = Cliffbot(LinkConfig(rate_bps=args.rate_bps), port, args.out, originals)
    print(json.dumps({"listening": args.listen}), flush=True)
    t0 = time.monotonic()
    linger_until = None
    with port:
        while time.monotonic() - t0 < args.timeout:
            now = time.monotonic() - t0
            for rep in bot.step(now, timeout_s=0.02):
                print(json.dumps(asdict(rep)), flush=True)
            if len(bot.reports) >= args.count and linger_until is None:
                linger_until = now + 1.0  # let the FIN / FIN_ACK exchange finish
            if linger_until is not None and now >= linger_until:
                return 0
    return 0 if len(bot.reports) >= args.count else 1


if __name__ == "__main__":
    sys.exit(main())
