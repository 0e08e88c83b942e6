"""Statistics helpers shared by the flag, the motion detector, the metrics and the outputs."""

from __future__ import annotations

from scipy.special import chdtri


def chi2_ppf(q: float, dof: float) -> float:
    """Chi-square quantile (scipy.stats.chi2.ppf(q, dof)) from scipy.special: importing scipy.stats costs a node
    ~0.4 s on an idle core (several seconds on a loaded one) for this one function."""
    return float(chdtri(dof, 1.0 - q))


#: an angle's 3-sigma above this [deg] says nothing about the angle (a heading still unknown, a yaw bank's spread):
#: insalign-align's CSV writes "unknown" and its JSON null, the node's ~/euler_error_3sigma NaN
SIGMA3_UNKNOWN_DEG = 180.0
