"""The one angle-wrapping helper (``fsw.core.geometry.wrap_angle``): floats and arrays alike."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import wrap_angle


def test_wrap_angle_folds_into_minus_pi_pi_and_keeps_the_direction() -> None:
    a = np.linspace(-25.0, 25.0, 5001)
    w = wrap_angle(a)
    assert np.all(np.abs(w) <= math.pi)
    turns = (a - w) / (2.0 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns), rtol=0, atol=1e-12)
    assert wrap_angle(math.pi) == math.pi and wrap_angle(-math.pi) == -math.pi  # pi itself stays
    for x, y in zip(a[::101], w[::101], strict=True):  # a float as an element of an array
        assert math.isclose(wrap_angle(float(x)), float(y), rel_tol=0, abs_tol=1e-15)
        assert isinstance(wrap_angle(float(x)), float)


def test_an_angle_in_range_comes_back_within_an_ulp() -> None:
    """Unlike ``(a + pi) % 2pi - pi``, which rounds a small angle to the ulp of pi."""
    a = np.concatenate([np.geomspace(1e-12, 3.1, 200), -np.geomspace(1e-12, 3.1, 200)])
    assert np.all(np.abs(wrap_angle(a) - a) <= np.spacing(np.abs(a)))
    assert wrap_angle(1e-9) == 1e-9 and (1e-9 + math.pi) % (2 * math.pi) - math.pi != 1e-9
