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


def write_doc_figures(outdir: Path) -> dict[str, float]:
    """The figures of docs/world.md (``python -m hil_sim.world.figures docs/img``); returns
    the SGBM figures quoted there."""
    import math

    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fsw.core.geometry import MastConfig, camera_pose_from_rover
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario
    from hil_sim.world.world import aim_at

    outdir.mkdir(parents=True, exist_ok=True)
    cam, mast = CameraConfig(), MastConfig()
    lab = load_scenario("lab")
    pose = camera_pose_from_rover(lab.rover_start, aim_at(lab, lab.rover_start, mast), mast)
    left, right = StereoRenderer(lab, cam, 2.0, 0).render(pose)
    pair_figure(left, right, outdir / "world_lab_pair.png",
                "lab, 640x480, mast aimed at the Cliff-bot (noise 2 DN)")
    elevation_figure(lab, outdir / "world_lab_truth.png", pose=pose, camera=cam)
    # The three scenarios from the rover start, looking down over the edge.
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, name in zip(axes, ("lab", "cliff", "mars"), strict=True):
        w = load_scenario(name)
        p = camera_pose_from_rover(w.rover_start, (math.radians(-65), math.radians(-35), 0.3),
                                   mast, w.plateau_z)
        ax.imshow(StereoRenderer(w, cam, 2.0, 0).render(p)[0], cmap="gray", vmin=0, vmax=255)
        ax.set_title(f"{name}: pan -65, tilt -35 deg")
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(outdir / "world_scenarios.png", dpi=90)
    plt.close(fig)
    # SGBM on a rendered pair against the renderer's own depth.
    p = camera_pose_from_rover(lab.rover_start, (math.radians(-60), math.radians(-30), 0.3), mast)
    r = StereoRenderer(lab, cam, 2.0, 0)
    left, right = r.render(p)
    depth = r.render_depth(p)
    sgbm = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=0, numDisparities=128, blockSize=5, P1=200,
                                 P2=800, uniquenessRatio=10, speckleWindowSize=100,
                                 speckleRange=2, mode=cv2.StereoSGBM_MODE_SGBM_3WAY)
    disp = sgbm.compute(left, right).astype(np.float32) / 16.0
    truth = cam.focal_px * cam.baseline_m / depth
    err = np.where(disp > 0, disp - truth, np.nan)
    err[:, :128] = np.nan
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, img, title, kw in (
            (axes[0], left, "left image", {"cmap": "gray"}),
            (axes[1], np.where(disp > 0, disp, np.nan), "SGBM disparity (px)", {"cmap": "viridis"}),
            (axes[2], err, "SGBM - true disparity (px)", {"cmap": "coolwarm", "vmin": -1, "vmax": 1})):
        im = ax.imshow(img, **kw)
        ax.set_title(title)
        ax.axis("off")
        if ax is not axes[0]:
            fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fig.savefig(outdir / "world_lab_sgbm.png", dpi=90)
    plt.close(fig)
    e = err[np.isfinite(err)]
    return {"median_px": float(np.median(e)),
            "robust_sigma_px": float(1.4826 * np.median(np.abs(e - np.median(e)))),
            "frac_over_1px": float(np.mean(np.abs(e) > 1.0)),
            "valid_frac": float(np.isfinite(err[:, 128:]).mean())}


if __name__ == "__main__":
    import sys

    figures = write_doc_figures(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/img"))
    print(", ".join(f"{k} {v:.3f}" for k, v in figures.items()))
