"""Seeded fractal noise fields for terrain relief and natural albedo texture.

Spectral synthesis: white noise shaped in the Fourier domain by a power law ``|f|^-beta``
between two wavelengths, so one call gives a multi-octave field (the sum of many octaves at
once) with a chosen slope. ``beta = 2`` looks like sand and rolling ground, ``beta = 1``
like speckled texture. Used by every scenario (docs/world.md, "Texture"); not an
docs/algorithm.md step, it is the world truth the algorithms are tested against.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]


def fractal_noise(
    shape: tuple[int, int],
    cell_m: float,
    rng: np.random.Generator,
    *,
    beta: float = 2.0,
    min_wavelength_m: float | None = None,
    max_wavelength_m: float | None = None,
) -> F32:
    """A zero-mean, unit-standard-deviation noise field with a power spectrum ``|f|^-beta``.

    ``shape`` is ``(ny, nx)`` cells of ``cell_m`` metres. Spatial frequencies below
    ``1 / max_wavelength_m`` and above ``1 / min_wavelength_m`` are removed (smooth roll-off),
    so the field has structure only between those two scales. Deterministic for the state of
    ``rng``.
    """
    ny, nx = shape
    if ny < 2 or nx < 2:
        raise ValueError(f"noise field shape {shape} is too small")
    white = rng.standard_normal((ny, nx)).astype(np.float32)
    spec = np.fft.rfft2(white)
    fy = np.fft.fftfreq(ny, d=cell_m)[:, None]
    fx = np.fft.rfftfreq(nx, d=cell_m)[None, :]
    f = np.sqrt(fx * fx + fy * fy)
    f[0, 0] = 1.0
    gain = f ** (-beta / 2.0)
    if max_wavelength_m is not None:
        f_lo = 1.0 / max_wavelength_m
        gain *= 1.0 - np.exp(-((f / f_lo) ** 4))
    if min_wavelength_m is not None:
        f_hi = 1.0 / min_wavelength_m
        gain *= np.exp(-((f / f_hi) ** 4))
    gain[0, 0] = 0.0
    field = np.fft.irfft2(spec * gain, s=(ny, nx)).astype(np.float32)
    std = float(field.std())
    if std <= 0.0:
        return np.zeros((ny, nx), np.float32)
    return (field - field.mean()) / std


def smooth_curve(
    n: int, step_m: float, rng: np.random.Generator, *, wavelength_m: float, beta: float = 2.0
) -> NDArray[np.float64]:
    """A 1-D zero-mean, unit-std random curve of ``n`` samples (for irregular edge lines)."""
    white = rng.standard_normal(max(n, 4))
    spec = np.fft.rfft(white)
    f = np.fft.rfftfreq(white.size, d=step_m)
    f[0] = 1.0
    gain = f ** (-beta / 2.0) * np.exp(-((f * wavelength_m / 2.0) ** 4))
    gain[0] = 0.0
    curve = np.fft.irfft(spec * gain, n=white.size)[:n]
    std = float(curve.std())
    return (curve - curve.mean()) / std if std > 0 else np.zeros(n)
