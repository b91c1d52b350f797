"""Natural albedo texture for a heightfield, with baked sun shading.

The albedo is a multi-scale fractal field (all octaves between ``finest_m`` and
``coarsest_m`` at once, spectral slope ``spectral_slope``), modulated per rock so rocks
stand out from sand, then multiplied by Lambertian shading from the terrain normals under a
fixed sun (view independent, so both cameras of the stereo pair see the same brightness),
with cast shadows where the scenario asks for them (``cast_shadows``; ``hil_sim.world.shadow``).
Textureless regions get one constant albedo and no shading, so stereo finds nothing to
match there (the paper's left part of the sandpit; docs/algorithm.md §3.4, §7). The renderer adds
a 2.5 mm detail texture scaled by :func:`make_texture`'s ``detail`` map (docs/world.md).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil_sim.world.config import TextureConfig
from hil_sim.world.noise import fractal_noise
from hil_sim.world.shadow import cast_shadow

F32 = NDArray[np.float32]


def sun_vector(cfg: TextureConfig) -> NDArray[np.float64]:
    """Unit vector toward the sun in the world frame."""
    az, el = math.radians(cfg.sun_azimuth_deg), math.radians(cfg.sun_elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def shading(height: F32, cell_m: float, cfg: TextureConfig) -> F32:
    """Lambertian shading ``ambient + (1 - ambient) * lit * max(0, n . sun)`` per cell, where
    ``lit`` is the sun's visibility (:func:`hil_sim.world.shadow.cast_shadow` when the
    scenario has ``cast_shadows``, else 1): a cell in a cast shadow gets the ambient light only.
    """
    gy, gx = np.gradient(height.astype(np.float32), cell_m)
    sx, sy, sz = sun_vector(cfg)
    ndots = np.clip((-gx * sx - gy * sy + sz) / np.sqrt(gx * gx + gy * gy + 1.0), 0.0, None)
    if cfg.cast_shadows:
        ndots = ndots * cast_shadow(height, cell_m, cfg.sun_azimuth_deg, cfg.sun_elevation_deg)
    return (cfg.ambient + (1.0 - cfg.ambient) * ndots).astype(np.float32)


def make_texture(
    height: F32,
    cell_m: float,
    cfg: TextureConfig,
    rng: np.random.Generator,
    *,
    rock_id: NDArray[np.int32] | None = None,
    textureless: NDArray[np.bool_] | None = None,
) -> tuple[F32, F32]:
    """``(albedo, detail)`` for the heightfield: albedo in ``[0, 1]``, detail amplitude.

    ``rock_id`` (``-1`` = no rock) gives each rock its own brightness and a coarser grain;
    ``textureless`` cells get ``cfg.textureless_albedo`` and zero detail.
    """
    shape = height.shape
    finest = max(cfg.finest_m, 2.0 * cell_m)
    coarsest = max(cfg.coarsest_m, 2.0 * finest)
    grain = fractal_noise(shape, cell_m, rng, beta=cfg.spectral_slope,
                          min_wavelength_m=finest, max_wavelength_m=coarsest)
    albedo = cfg.base_albedo * (1.0 + cfg.contrast * grain)
    detail = np.ones(shape, np.float32)
    if rock_id is not None and (rock_id >= 0).any():
        n_rocks = int(rock_id.max()) + 1
        tone = rng.uniform(0.65, 1.35, n_rocks).astype(np.float32)
        on_rock = rock_id >= 0
        blotch = fractal_noise(shape, cell_m, rng, beta=2.0, min_wavelength_m=finest,
                               max_wavelength_m=0.3)
        rock_albedo = cfg.base_albedo * tone[np.maximum(rock_id, 0)] * (1.0 + 0.3 * blotch)
        albedo = np.where(on_rock, rock_albedo, albedo)
        detail[on_rock] = 1.3
    albedo = albedo * shading(height, cell_m, cfg)
    if textureless is not None:
        albedo = np.where(textureless, np.float32(cfg.textureless_albedo), albedo)
        detail[textureless] = 0.0
    albedo = np.clip(albedo, 0.02, 0.98).astype(np.float32)
    return albedo, detail
