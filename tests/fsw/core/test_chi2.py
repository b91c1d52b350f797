"""The chi-square quantile of the registration's split check without scipy.stats (issue 15:
importing it cost the flight process ~45 MB): scipy's values to 1e-12."""

from __future__ import annotations

import pytest
from scipy.stats import chi2

from fsw.core.registration.registration_stats import chi2_quantile, chi2_sf


@pytest.mark.parametrize("dof", range(1, 13))
def test_quantile_and_survival_match_scipy(dof: int) -> None:
    for p in (0.01, 0.5, 0.9, 0.99, 0.999, 0.9999):
        assert chi2_quantile(p, dof) == pytest.approx(chi2.ppf(p, dof), rel=1e-12)
    for x in (0.05, 1.0, 5.0, 22.46, 60.0):
        assert chi2_sf(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-12)
    assert chi2_sf(0.0, dof) == 1.0 and chi2_sf(-1.0, dof) == 1.0


@pytest.mark.parametrize(("p", "dof"), [(0.0, 3), (1.0, 3), (float("nan"), 3), (0.5, 0)])
def test_bad_arguments_are_refused(p: float, dof: int) -> None:
    with pytest.raises(ValueError):
        chi2_quantile(p, dof)
