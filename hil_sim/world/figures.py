"""Figures of the world truth for humans: the elevation map with the true edge, the
Cliff-bot, the rover start and a camera's view, and a stereo pair side by side
(``safer-hil render``, docs/world.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fsw.core.geometry import CameraConfig, CameraPose
from hil_sim.world.raytrace import Heightfield, cast_rays, pixel_rays
from hil_sim.world.world import World


def view_outline(world: World, pose: CameraPose, camera: CameraConfig, per_side: int = 24
                 ) -> np.ndarray:
    """World ``(x, y)`` where the image border's rays meet the terrain (``(n, 2)``)."""
    w, h = camera.width_px - 1.0, camera.height_px - 1.0
    s = np.linspace(0.0, 1.0, per_side)
    us = np.concatenate([s * w, np.full(per_side, w), (1 - s) * w, np.zeros(per_side)])
    vs = np.concatenate([np.zeros(per_side), s * h, np.full(per_side, h), (1 - s) * h])
    d = np.stack([pixel_rays(pose.R, camera.K, np.array([u]), np.array([v]))[0, 0]
                  for u, v in zip(us, vs, strict=True)])
    hf = Heightfield.from_array(world.ground, world.x0, world.y0, world.cell_m)
    t = cast_rays(hf, pose.t, d)
    ok = np.isfinite(t)
    return np.column_stack([pose.t[0] + t[ok] * d[ok, 0], pose.t[1] + t[ok] * d[ok, 1]])


def elevation_figure(world: World, path: Path, *, pose: CameraPose | None = None,
                     camera: CameraConfig | None = None) -> None:
    """Write a PNG of the truth elevation with the edge, Cliff-bot, rover and view."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 7))
    im = ax.imshow(world.height, origin="lower", extent=world.extent, cmap="terrain",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label="elevation (m)")
    if world.textureless.any():
        ax.contour(np.asarray(world.textureless, float), levels=[0.5], origin="lower",
                   extent=world.extent, colors="m", linewidths=1.0)
    if len(world.edge_xy):
        ax.plot(world.edge_xy[:, 0], world.edge_xy[:, 1], "r-", lw=1.2, label="true edge")
    cb = world.cliffbot
    for m in cb.markers:
        c = m.corners_world
        ax.fill(c[:, 0], c[:, 1], color="k", alpha=0.6)
    ax.plot(cb.x, cb.y, "ks", ms=4, label="Cliff-bot")
    x, y, yaw = world.rover_start
    ax.arrow(x, y, 0.5 * np.cos(yaw), 0.5 * np.sin(yaw), width=0.06, color="b",
             label="rover start")
    if pose is not None and camera is not None:
        outline = view_outline(world, pose, camera)
        if len(outline):
            ax.plot(np.append(outline[:, 0], outline[0, 0]), np.append(outline[:, 1],
                    outline[0, 1]), "y-", lw=1.2, label="camera view")
    g = world.map_grid
    ax.add_patch(plt.Rectangle((g.origin_x_m, g.origin_y_m), g.nx * g.cell_m, g.ny * g.cell_m,
                               fill=False, ls="--", ec="0.3", label="FSW map grid"))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{world.name} (seed {world.seed}): truth elevation, {world.cell_m * 100:g} cm cells")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pair_figure(left: np.ndarray, right: np.ndarray, path: Path, title: str = "") -> None:
    """Write the left and right images side by side as one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    for ax, img, name in zip(axes, (left, right), ("left", "right"), strict=True):
        ax.imshow(img, cmap="gray", vmin=0, vmax=255)
        ax.set_title(name)
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
