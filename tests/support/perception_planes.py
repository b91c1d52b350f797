"""Synthetic rectified stereo pairs of a textured plane (test helper, no world needed)."""

from __future__ import annotations

import cv2
import numpy as np

from fsw.core.geometry import CameraConfig, CameraPose


def texture(seed: int, size: int = 1024, blur_px: float = 1.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 255, (size, size)).astype(np.float32)
    return cv2.GaussianBlur(t, (0, 0), blur_px)


def render_plane(
    camera: CameraConfig,
    pose: CameraPose,
    tex: np.ndarray,
    tex_cell_m: float,
    z_plane: float = 0.0,
    flat_box: tuple[float, float, float, float] | None = None,
    noise_sigma: float = 1.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Left/right images of the horizontal plane z = z_plane with albedo ``tex``.

    ``flat_box`` (x0, x1, y0, y1) paints a constant (textureless) patch.
    """
    rng = np.random.default_rng(seed)
    K = camera.K
    h, w = camera.height_px, camera.width_px
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    out = []
    for p in (pose, pose.right(camera.baseline_m)):
        rays_w = rays_c @ p.R.T
        s = (z_plane - p.t[2]) / rays_w[..., 2]
        X = p.t[0] + s * rays_w[..., 0]
        Y = p.t[1] + s * rays_w[..., 1]
        mx = (X / tex_cell_m).astype(np.float32) % tex.shape[1]
        my = (Y / tex_cell_m).astype(np.float32) % tex.shape[0]
        img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        if flat_box is not None:
            x0, x1, y0, y1 = flat_box
            img[(x0 <= X) & (x1 >= X) & (y0 <= Y) & (y1 >= Y)] = 128.0
        img[s <= 0] = 0.0
        img = img + rng.normal(0, noise_sigma, img.shape)
        out.append(np.clip(np.round(img), 0, 255).astype(np.uint8))
    return out[0], out[1]
