"""Statistics helpers shared by the flag, the motion detector and the metrics."""

from __future__ import annotations

from scipy.special import chdtri


def chi2_ppf(q: float, dof: float) -> float:
    """Chi-square quantile (scipy.stats.chi2.ppf(q, dof)) from scipy.special: importing scipy.stats costs a node
    ~0.4 s on an idle core (several seconds on a loaded one) for this one function."""
    return float(chdtri(dof, 1.0 - q))
