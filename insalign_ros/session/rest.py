"""Statistics of the gyros at rest (``core: auto``): robust block means, their variance, and the gyro bias they give
(docs/motion_detector.md)."""

from __future__ import annotations

import math

import numpy as np

from ..core import earth
from ..core.stats import chi2_ppf

D2R = math.pi / 180.0

#: block length of the rest-window gyro means [s] (:func:`rest_rate_mean`)
REST_BLOCK_S = 1.0


def block_variance(block_means_b: np.ndarray) -> np.ndarray:
    """Per-axis variance [rad^2/s^2] of one block mean from n block means (n, 3): the MAD's robust sigma squared at
    the 95 % upper chi-square bound of a variance from n samples (a few blocks of a person getting in do not
    inflate it)."""
    x = np.asarray(block_means_b, float)
    n = x.shape[0]
    s = 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)
    return (s * s) * (n - 1) / chi2_ppf(0.05, n - 1)


def rest_rate_mean(block_means_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robust mean angular rate over a rest window from its ``REST_BLOCK_S`` block means (n, 3) [rad/s]: the
    per-axis median, and the variance of that median [rad^2/s^2] (:func:`block_variance` / n, x pi/2 for a median).

    Blocks average the engine and sway vibration; the median drops the few blocks of a person getting in (the
    load step tilts the body by ~0.5 deg: in a plain mean over 40 s that is a 45 deg/h bias error)."""
    x = np.asarray(block_means_b, float)
    return np.median(x, axis=0), block_variance(x) * (0.5 * math.pi) / x.shape[0]


class _BlockMean:
    """Running ``REST_BLOCK_S`` mean of the gyro rate omega_ib_b [rad/s] from samples that are each the mean rate
    over their interval; a block with any sample not at rest is dropped."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.int_w, self.T, self.ok = np.zeros(3), 0.0, True

    def add(self, dt: float, w: np.ndarray, at_rest: bool = True) -> np.ndarray | None:
        """Add a sample over ``dt`` [s]; the block's mean when this sample completes a block at rest, else None."""
        self.int_w += w * dt
        self.T += dt
        self.ok &= at_rest
        if self.T < REST_BLOCK_S:
            return None
        mean, ok = self.int_w / self.T, self.ok
        self.reset()
        return mean if ok else None

    def add_rest_rows(self, prev: float | None, T: list, W: np.ndarray) -> list[np.ndarray]:
        """:meth:`add` at rest for each row (stamp ``T[k]``, rate ``W[k]``) after the stamp ``prev`` (None: the first
        row only starts the time line; rows not after the one before are skipped): the block means completed, in
        order. The same IEEE operations per axis in Python floats (one numpy operation per row cost ~1 us)."""
        x, y, z = self.int_w.tolist()
        tt, out = self.T, []
        for t, (wx, wy, wz) in zip(T, W.tolist()):
            if prev is not None and t > prev:
                dt = t - prev
                x += wx * dt
                y += wy * dt
                z += wz * dt
                tt += dt
                if tt >= REST_BLOCK_S:
                    if self.ok:
                        out.append(np.array([x / tt, y / tt, z / tt]))
                    x = y = z = tt = 0.0
                    self.ok = True
            prev = t
        self.int_w, self.T = np.array([x, y, z]), tt
        return out


def gyro_bias_from_rest(omega_mean_b: np.ndarray, var_mean_b: np.ndarray, C_b_n: np.ndarray, lat_rad: float,
                        heading_trusted: bool, gyro_bias_instability_deg_h: float, sigma_level_rad: float = 0.0,
                        sigma_yaw_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gyro bias [rad/s, body] and its 3x3 covariance [rad^2/s^2] from the mean rate over a rest window.

    At rest the gyros measure ``omega_mean_b = b_g + C_b_n^T Omega_ie_n`` + noise, with
    ``Omega_ie_n = Omega [0, cos L, sin L]`` (ENU). The Up component (``Omega sin L``) is known from the latitude and
    the level; the horizontal one (magnitude ``Omega cos L``, towards North) only when the heading is trusted.
    Subtracted: the known part. Covariance: the variance of the mean ``var_mean_b`` (per body axis; white noise
    alone: ``ARW^2 / T``, see :func:`rest_rate_mean`), the bias instability (the Allan-deviation floor: averaging
    longer does not beat it), the Earth-rate projection error of the attitude uncertainty, and (heading not
    trusted) the horizontal Earth rate itself: North uniform on the horizontal circle, variance
    ``(Omega cos L)^2 / 2`` per horizontal axis.
    """
    C_b_n = np.asarray(C_b_n, float)
    w_ie_n = earth.omega_ie_n(lat_rad)
    known_n = w_ie_n if heading_trusted else np.array([0.0, 0.0, w_ie_n[2]])
    b = np.asarray(omega_mean_b, float) - C_b_n.T @ known_n
    var = np.asarray(var_mean_b, float) + (gyro_bias_instability_deg_h * D2R / 3600.0) ** 2
    Om = earth.OMEGA_IE_RAD_S
    var += (Om * sigma_level_rad) ** 2  # the Up axis is tilted by the level error
    P_n = np.zeros((3, 3))
    if heading_trusted:
        var += (Om * math.cos(lat_rad) * sigma_yaw_rad) ** 2
    else:
        P_n[0, 0] = P_n[1, 1] = 0.5 * (Om * math.cos(lat_rad)) ** 2
    return b, np.diag(var) + C_b_n.T @ P_n @ C_b_n


def zupt_nis_mean(zupt_nis) -> float:
    """The mean NIS per dof of the accepted zero-velocity updates that :func:`static_heading_support` uses (0 under
    50 of them)."""
    return float(np.mean(zupt_nis)) if len(zupt_nis) >= 50 else 0.0


def static_heading_support(P: np.ndarray, zupt_support: tuple[int, int], zupt_nis, floor_rad: float,
                           nis_mean: float | None = None) -> tuple[np.ndarray, str]:
    """Parked (``core: auto``): the heading variance the flag sees in the attitude covariance ``P`` (ENU, changed in
    place and returned, with the reason) is at least the gyrocompassing floor ``floor_rad`` (eps_east / (omega_ie
    cos lat)), squared, scaled by 1 / the fraction of zero-velocity updates accepted (``zupt_support`` (asked,
    accepted): under 0.9, from 20 asked) and by their mean NIS per dof (``zupt_nis``) when over 2 (from 50). A real
    parked car: 992 of 2,991 accepted, yaw 3.7 deg off at a 2.24 3-sigma."""
    asked, ok = zupt_support
    k, why = 1.0, ""
    if asked >= 20 and ok < 0.9 * asked:  # a few refused (a person getting in) say nothing about the model
        k = asked / max(ok, 1)
    nis = zupt_nis_mean(zupt_nis) if nis_mean is None else nis_mean
    if nis > 2.0:
        k *= nis
    if k > 1.0 + 1e-9:
        P[2, :] *= math.sqrt(k)
        P[:, 2] *= math.sqrt(k)
        why = (f"heading variance x{k:.2f}: zero-velocity updates accepted {ok} of {asked}"
               + (f", mean NIS per dof {nis:.2f}" if nis > 2.0 else ""))
    if math.isfinite(floor_rad) and P[2, 2] < floor_rad * floor_rad:
        P[2, 2] = floor_rad * floor_rad
    return P, why
