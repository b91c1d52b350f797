"""The Cliff-bot on the bench: receive the map, verify it, decode it, report (docs/algorithm.md §6.6).

:class:`Cliffbot` runs the flight :class:`~fsw.comm.link_receiver.LinkReceiver` over any
``RadioPort`` (the simulated channel, UDP, a serial modem). For every map the link
accepts (whole-map SHA-256 already checked by the link) it decodes the container, checks
the decoded map against the original when it knows it, and returns a
:class:`CliffbotReport`; :func:`write_figure13` draws the paper's Figure 13 (original beside
received, lighter = higher).

As a separate process: ``safer-hil cliffbot`` (``hil_sim/commands/cliffbot.py``; the old
``python -m hil_sim.cliffbot_receiver`` still runs it). It prints one JSON line per link
event and per map and exits 0 once ``--count`` maps arrived and the link's close has ended.

Saving a received map (its ``.npy`` and figure in ``out_dir``) may meet a full or failing
disk (``ENOSPC``, ``EIO``): the map stays received, verified and decoded in memory
(``maps``), the report says ``save_error`` (one line), a ``MAP_NOT_SAVED`` line goes to
stderr, and no half-written file is left under a final name.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver
from fsw.core.codec.hazard import relief
from fsw.core.codec.mapcodec import MapCodecError, decode_map
from fsw.drivers.radio import RadioPort
from fsw.framework.storage import describe


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
    save_error: str = ""  # the map arrived but could not be written to out_dir (one line)


class Cliffbot:
    """Receiver, decoder and reporter; ``step(now_s)`` pumps the radio once."""

    def __init__(self, link: LinkConfig, port: RadioPort, out_dir: Path | None = None,
                 originals: dict[int, NDArray[np.float32]] | None = None,
                 decode: bool = True) -> None:
        self.rx = LinkReceiver(link)
        self.port = port
        self.out_dir = out_dir
        self.originals = originals or {}
        self.reports: list[CliffbotReport] = []
        self.maps: dict[int, NDArray[np.float32]] = {}
        self.decode = decode

    def step(self, now_s: float, timeout_s: float = 0.0) -> list[CliffbotReport]:
        d = self.port.recv(timeout_s, now_s)
        while d is not None:
            self.rx.receive(d, now_s)
            d = self.port.recv(0.0, now_s)
        for pkt in self.rx.poll(now_s):
            self.port.send(pkt, now_s)
        return [rep for rep, _ in self.collect()]

    def collect(self) -> list[tuple[CliffbotReport, bytes]]:
        """Report every map the link verified since the last call, with its bytes."""
        new = []
        got = self.rx.take_map()
        while got is not None:
            new.append((self._report(*got), got[1]))
            got = self.rx.take_map()
        self.reports += [rep for rep, _ in new]
        return new

    def _report(self, map_id: int, data: bytes) -> CliffbotReport:
        if not self.decode:
            return CliffbotReport(map_id, len(data), False, "not decoded (--no-decode)", (0, 0), 0,
                                  0.0, None, None, "")
        try:
            dec = decode_map(data)
        except MapCodecError as exc:
            return CliffbotReport(map_id, len(data), False, str(exc), (0, 0), 0, 0.0, None, None, "")
        z = dec.z
        self.maps[map_id] = z
        orig = self.originals.get(map_id)
        max_err = unknown_ok = None
        png = save_error = ""
        if orig is not None and orig.shape == z.shape:
            k = np.isfinite(orig)
            max_err = float(np.abs(z[k].astype(np.float64) - orig[k]).max()) if k.any() else 0.0
            unknown_ok = bool(np.array_equal(np.isnan(z), ~k))
        if self.out_dir is not None:
            path = self.out_dir / f"cliffbot_map_{map_id}.png"
            left = orig if orig is not None and orig.shape == z.shape else z
            h = dec.header
            outlines = None
            title = f"map {map_id}: {len(data)} bytes, bound {h.error_bound_m:.3f} m"
            label = f"hazard: relief >= {h.hazard_threshold_m:.2f} m"
            if h.hazard:  # the obstacles (relief >= the hazard threshold) outlined in both
                outlines = (relief(left, h.cell_m, h.relief_disc_m) >= h.hazard_threshold_m,
                            relief(z, h.cell_m, h.relief_disc_m) >= h.hazard_threshold_m)
            try:
                self.out_dir.mkdir(parents=True, exist_ok=True)
                _atomic(path, lambda p: write_figure13(left, z, p, title, outlines=outlines, cell_m=h.cell_m,
                                                       outline_label=label))
                _atomic(self.out_dir / f"cliffbot_map_{map_id}.npy", lambda p: np.save(p, z))
                png = str(path)
            except OSError as exc:  # full or failing disk: the map stays received and decoded
                save_error = describe(exc)
                print(f"cliffbot: MAP_NOT_SAVED map {map_id} received and verified, not saved in {self.out_dir}: "
                      f"{save_error}", file=sys.stderr)
        return CliffbotReport(map_id, len(data), True, "", z.shape, int(np.isfinite(z).sum()),
                              dec.header.error_bound_m, max_err, unknown_ok, png, save_error)


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write`` to a temporary name beside ``path``, then rename it over ``path``: a failed
    write leaves no partial file under the final name (the temporary is removed)."""
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        write(tmp)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


UNKNOWN_COLOUR = "#2f6fd0"  # unknown cells in Figure 13 (blue: never read as a hazard)
HAZARD_COLOUR = "#e02020"  # the outlines of ``outlines`` (the hazards)


def write_figure13(original: NDArray[np.floating], received: NDArray[np.floating], path: Path,
                   title: str = "", outlines: tuple[NDArray[np.bool_], NDArray[np.bool_]] | None = None,
                   cell_m: float | None = None, outline_label: str = "hazard") -> None:
    """Paper Figure 13: grayscale elevation, original (left) and transmitted (right), drawn as
    every map picture is (row 0 = lowest y at the bottom, ``origin="lower"``, as ``map.png``);
    axes in metres from the map's corner when ``cell_m`` is given, else in cells. Unknown cells
    are :data:`UNKNOWN_COLOUR`; ``outlines`` (one mask per panel, e.g. the obstacles) are drawn as
    :data:`HAZARD_COLOUR` contours; a legend names both when the picture has them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    both = np.concatenate([original[np.isfinite(original)], received[np.isfinite(received)]])
    lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.2))
    cmap = matplotlib.colormaps["gray"].with_extremes(bad=UNKNOWN_COLOUR)
    outlined = False
    for ax, img, name in zip(axes, (original, received), ("original", "received by the Cliff-bot"),
                             strict=True):
        ny, nx = img.shape
        scale, unit = (cell_m, "m") if cell_m else (1.0, "cells")
        extent = (0.0, nx * scale, 0.0, ny * scale)
        im = ax.imshow(img, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest", origin="lower", extent=extent)
        if outlines is not None:
            mask = outlines[0] if img is original else outlines[1]
            if mask.any():
                outlined = True
                ax.contour(mask.astype(np.float32), levels=[0.5], colors=HAZARD_COLOUR, linewidths=0.6,
                           origin="lower", extent=extent)
        ax.set_title(name)
        ax.set_xlabel(f"x from the map's corner ({unit})")
        ax.set_ylabel(f"y ({unit})")
    fig.colorbar(im, ax=axes, shrink=0.8, label="elevation [m]")
    handles: list[Patch | Line2D] = []
    if not (np.isfinite(original).all() and np.isfinite(received).all()):
        handles.append(Patch(facecolor=UNKNOWN_COLOUR, label="unknown"))
    if outlined:
        handles.append(Line2D([], [], color=HAZARD_COLOUR, linewidth=1.5, label=outline_label))
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hil_sim.cliffbot_receiver ARGS`` = ``safer-hil cliffbot ARGS``."""
    from hil_sim.cli import main as hil_main

    return hil_main(["cliffbot", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
