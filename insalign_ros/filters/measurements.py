"""Measurement models as data: each carries its value and covariance, validates itself, names its counter and gives
``(z, H, N)`` for a core's error convention from the core's linearisation point (navlie's ``MeasurementModel``,
pyins' ``compute_matrices() -> (z, H, R)``). One pipeline fuses them all (filters/update.py):
``core.update(model) -> UpdateResult`` and ``core.predict(model) -> UpdateResult`` (nothing changed: the gate).

Constructors (stamps [s] are data time, arrays are copied to float):

* ``GnssPosition(stamp_s, p_e, R_e)``: an antenna position fix, ECEF [m], 3x3 covariance [m^2] (a ``GnssFix``);
  ``GnssPosition.of(fix)`` from a ``GnssFix``.
* ``GnssVelocity(stamp_s, v_n, R_n)``: the antenna's velocity relative to Earth in ENU [m/s], 3x3 [m^2/s^2];
  ``GnssVelocity.of(vel)`` from a ``core.types.GnssVelocity``.
* ``ZeroVelocity(stamp_s, sigma_v_m_s)``: at rest relative to Earth, 1-sigma [m/s] per axis.
* ``ZeroAngularRate(omega_mean_b, R_b, stamp_s=nan)``: at rest over a window ending now; the gyros' mean
  [rad/s, body FLU] and its 3x3 covariance [rad^2/s^2].
* ``GyroBiasPrior(b_g_b, P_b_g_b)``: a direct observation of the gyro bias [rad/s, body FLU] with its 3x3
  covariance [rad^2/s^2] (the bias measured at rest, or learned by a core being replaced), fused right after
  ``initialize`` by the cores that keep the gyro bias block.
* ``NonHolonomic``, ``GnssHeading`` and ``WheelSpeed``: filters/vehicle_models.py (issue 25).

Error conventions a core declares (``AlignmentCore.convention``), with the state layout the models rely on:

* ``"eci_left"``: ECI left-invariant SE2(3), truth ``X = X_hat exp(xi)``, ``xi = [phi, nu, rho]`` at 0:9 (body
  frame), gyro bias 9:12 and accelerometer bias 12:15 where kept (liekf, pi_liekf, iekf);
* ``"eci_ekf"``: ECI conventional, ``C = exp(psi_x) C_hat``, ``v = v_hat + dv``, ``p = p_hat + dp``, psi 0:3,
  dv 3:6, dp 6:9, b_g 9:12, b_a 12:15 (ekf);
* ``"earth_left"``: the Earth-frame IEKF of filters/earth_iekf.py (its zero-velocity model, eqs. (50)-(55));
* ``"static"``: the static cores' eq. (34) model: their zero-velocity step is their own fused kernel (a hook).

The linearisation point of the ECI conventions is the core itself, flushed: ``C`` (C_b_i), ``v`` (v_i [m/s]),
``p`` (p_i [m]), ``omega_b`` (bias-corrected omega_ib_b of the newest sample [rad/s]), ``b_g`` [rad/s],
``lever_b`` (antenna lever arm, body [m]), ``t_s``, ``t0_s`` (ECI == ECEF at t0), ``_n_states``, ``cfg``.
A core accepts (``core.accepts``) every model with terms for its convention whose ``needs`` (state blocks beyond the
navigation states, e.g. ``gyro_bias``) it keeps (``core.state_blocks``), plus the models of its own hook
(``own_models``: the static cores' zero velocity). A new sensor is a new model: a class with ``check``,
``counter``/``label`` and one ``terms`` function per convention it supports (:func:`jacobian`); no core changes.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import earth, lie
from ..core.types import GnssFix
from ..core.types import GnssVelocity as _GnssVelocityData
from .checks import check_fix, check_velocity
from .eci_batch import gnss_terms_eci
from .kalman import spd3
from .update import TERMS as _TERMS
from .update import jacobian  # noqa: F401  (the models' registration, re-exported)

_I3 = np.eye(3)

def conventions(model: type) -> tuple[str, ...]:
    """The error conventions ``model`` has terms for."""
    return tuple(c for (m, c) in _TERMS if m is model)


class Measurement:
    """Base of the measurement models. Class attributes: ``counter`` (the core's counters ``counter`` and
    ``counter_rejected``), ``label`` (reject reasons), ``fading`` (the core's adaptive fading memory applies),
    ``nis_gate`` (None: the core's gate; a number: this model's own chi-square gate, 0 = off), ``weighs_hypotheses``
    (a yaw hypothesis bank weighs its components by this model's innovation likelihood)."""

    counter = "measurement"
    label = "measurement"
    fading = True
    nis_gate: float | None = None
    weighs_hypotheses = True
    #: a position update: PI-LIEKF's correction (eq. (30)) and its update clock (filters/pi_liekf.py)
    is_position = False
    #: the state blocks (``AlignmentCore.state_blocks``) the model's Jacobian needs besides the navigation states
    needs: frozenset = frozenset()

    def check(self) -> str:
        """Why the measurement is unusable, or ""."""
        return ""

    def terms(self, core):
        """(z, H, N) for ``core.convention`` at the core's (flushed) linearisation point."""
        fn = _TERMS.get((type(self), core.convention))
        if fn is None:
            raise ValueError(f"{type(self).__name__} has no model for the {core.convention!r} convention")
        return fn(self, core)


class GnssPosition(GnssFix, Measurement):
    """A GNSS antenna position fix (ECEF [m], covariance [m^2]); PI-LIEKF eqs. (10), (11), (42), (43)."""

    counter = "gnss"
    label = "GNSS"
    is_position = True

    @classmethod
    def of(cls, fix: GnssFix) -> "GnssPosition":
        return fix if isinstance(fix, cls) else cls(fix.stamp_s, fix.p_e, fix.R_e)

    def check(self) -> str:
        return check_fix(self)


class GnssVelocity(_GnssVelocityData, Measurement):
    """A GNSS antenna velocity relative to Earth in ENU [m/s], covariance [m^2/s^2] (docs/inmotion_cores.md)."""

    counter = "gnss_vel"
    label = "GNSS velocity"

    @classmethod
    def of(cls, vel) -> "GnssVelocity":
        return vel if isinstance(vel, cls) else cls(vel.stamp_s, vel.v_n, vel.R_n)

    def check(self) -> str:
        return check_velocity(self.v_n, self.R_n)


class ZeroVelocity(Measurement):
    """At rest relative to Earth at ``stamp_s`` [s], 1-sigma ``sigma_v_m_s`` [m/s] per axis."""

    counter = "zupt"
    label = "zero velocity"
    fading = False
    nis_gate = 0.0

    def __init__(self, stamp_s: float, sigma_v_m_s: float):
        self.stamp_s = float(stamp_s)
        self.sigma_v_m_s = float(sigma_v_m_s)

    def check(self) -> str:
        s = self.sigma_v_m_s
        return "" if math.isfinite(s) and s > 0 else f"sigma_v_m_s {s!r} must be finite and > 0"


class ZeroAngularRate(Measurement):
    """At rest over a window ending now: the gyros' mean ``omega_mean_b`` [rad/s] with covariance ``R_b``
    [rad^2/s^2] read ``b_g + C_b_i^T omega_ie_i``. Own NIS gate: chi-square 3 dof, p = 1e-5 (a person getting in is
    rejected); no fading; it does not weigh yaw hypotheses (they differ only by the horizontal Earth rate)."""

    counter = "zero_rate"
    label = "zero rate"
    needs = frozenset({"gyro_bias"})
    fading = False
    nis_gate = 25.9
    weighs_hypotheses = False

    def __init__(self, omega_mean_b, R_b, stamp_s: float = math.nan):
        self.omega_mean_b = np.asarray(omega_mean_b, float)
        self.R_b = np.asarray(R_b, float)
        self.stamp_s = float(stamp_s)

    def check(self) -> str:
        if self.omega_mean_b.shape != (3,) or self.R_b.shape != (3, 3):
            return f"bad shapes omega {self.omega_mean_b.shape}, R {self.R_b.shape}"
        if not (np.all(np.isfinite(self.omega_mean_b)) and np.all(np.isfinite(self.R_b))):
            return "non-finite rate or covariance"
        return "" if spd3(self.R_b) else "covariance not positive definite"


class GyroBiasPrior(Measurement):
    """A prior of the gyro bias: ``b_g_b`` [rad/s, body FLU] with covariance ``P_b_g_b`` [rad^2/s^2] (the hand-over of
    ``core: auto`` gives the bias measured at rest; a re-seeded core the bias its predecessor learned, which already
    holds the grade's prior). Observed directly, with the information it adds to the core's own knowledge of the block,
    so that the block becomes (``b_g_b``, ``P_b_g_b``) where it is uncorrelated with the rest (right after
    ``initialize``): the grade's prior is not counted twice, and a prior the core already holds changes nothing. No
    gate, no fading; it does not weigh yaw hypotheses (every hypothesis gets the same body-frame bias)."""

    counter = "gyro_bias_prior"
    label = "gyro bias prior"
    needs = frozenset({"gyro_bias"})
    fading = False
    nis_gate = 0.0
    weighs_hypotheses = False

    def __init__(self, b_g_b, P_b_g_b, stamp_s: float = math.nan):
        self.b_g_b = np.asarray(b_g_b, float).reshape(-1)
        self.P_b_g_b = np.asarray(P_b_g_b, float)
        self.stamp_s = float(stamp_s)

    def check(self) -> str:
        if self.b_g_b.shape != (3,) or self.P_b_g_b.shape != (3, 3):
            return f"bad shapes b_g {self.b_g_b.shape}, P {self.P_b_g_b.shape}"
        if not (np.all(np.isfinite(self.b_g_b)) and np.all(np.isfinite(self.P_b_g_b))):
            return "non-finite bias or covariance"
        return "" if spd3(self.P_b_g_b) else "covariance not positive definite"


# ------------------------------------------------------------------------------------------ ECI terms
def _floored(R_e: np.ndarray, floor_m: float) -> np.ndarray:
    """The fix covariance with its smallest eigenvalue raised to ``floor_m^2`` (the same in ECEF and ECI)."""
    floor2 = floor_m ** 2
    if floor2 > 0:
        lo = float(np.linalg.eigvalsh(0.5 * (R_e + R_e.T)).min())
        if lo < floor2:
            R_e = R_e + (floor2 - lo) * np.eye(3)
    return R_e


def _position_i(m: GnssPosition, core):
    R_e = _floored(np.asarray(m.R_e, float), getattr(core.cfg, "gnss_sigma_floor_m", 0.0))
    Cei = earth.C_e_i(core.t_s, core.t0_s)
    return Cei @ np.asarray(m.p_e, float), Cei @ R_e @ Cei.T, R_e


@jacobian(GnssPosition, "eci_left")
def _position_eci_left(m: GnssPosition, core):
    """Left-invariant position innovation of the antenna at the lever arm l (eqs. (42), (43)):
    p_ant = p + C exp(phi) l, z = C^T (p_gps - p) - l = rho - l_x phi; N = C^T R_i C (one compiled call)."""
    R_e = _floored(np.asarray(m.R_e, float), getattr(core.cfg, "gnss_sigma_floor_m", 0.0))
    a = earth.OMEGA_IE_RAD_S * (core.t_s - core.t0_s)
    z, H, N = np.empty(3), np.zeros((3, core._n_states)), np.empty((3, 3))
    gnss_terms_eci(math.cos(a), math.sin(a), np.asarray(m.p_e, float), R_e, np.ascontiguousarray(core.C),
                   np.asarray(core.p, float), core.lever_b, z, H, N)
    return z, H, N


@jacobian(GnssPosition, "eci_ekf")
def _position_eci_ekf(m: GnssPosition, core):
    """p_ant = p + exp(psi_x) C l: z = p_gps - p - C l = dp - (C l)_x psi."""
    p_i, R_i, _ = _position_i(m, core)
    Cl = core.C @ core.lever_b
    H = np.zeros((3, core._n_states))
    H[:, 0:3] = -lie.hat3(Cl)
    H[:, 6:9] = _I3
    return p_i - core.p - Cl, H, R_i


def _velocity_i(m: GnssVelocity, core):
    """The ENU antenna velocity relative to Earth as the ECI inertial velocity at the estimated antenna position
    (the earth-rate term omega_ie x p_ant uses the estimate: its error, ~7e-5 m/s per metre, is neglected in H)."""
    Cei = earth.C_e_i(core.t_s, core.t0_s)
    p_ant_e = Cei.T @ (core.p + core.C @ core.lever_b)
    lat, lon, _ = earth.ecef_to_geodetic(p_ant_e)
    Cne = earth.C_n_e(lat, lon)
    v_i = Cei @ (Cne @ np.asarray(m.v_n, float) + np.cross(earth.OMEGA_IE_E, p_ant_e))
    M = Cei @ Cne
    return v_i, M @ np.asarray(m.R_n, float) @ M.T


@jacobian(GnssVelocity, "eci_left")
def _velocity_eci_left(m: GnssVelocity, core):
    """v_ant = v + C exp(phi) a, a = omega_ib_b x l: z = C^T (v_gps - v) - a = nu - a_x phi."""
    v_i, R_i = _velocity_i(m, core)
    a = np.cross(core.omega_b, core.lever_b)
    H = np.zeros((3, core._n_states))
    H[:, 0:3] = -lie.hat3(a)
    H[:, 3:6] = _I3
    Ct = core.C.T
    return Ct @ (v_i - core.v) - a, H, Ct @ R_i @ core.C


@jacobian(GnssVelocity, "eci_ekf")
def _velocity_eci_ekf(m: GnssVelocity, core):
    """v_ant = v + exp(psi_x) C a, a = omega_ib_b x l: z = v_gps - v - C a = dv - (C a)_x psi (the gyro-bias term
    of the lever-arm velocity, l x db_g, neglected)."""
    v_i, R_i = _velocity_i(m, core)
    Ca = core.C @ np.cross(core.omega_b, core.lever_b)
    H = np.zeros((3, core._n_states))
    H[:, 0:3] = -lie.hat3(Ca)
    H[:, 3:6] = _I3
    return v_i - core.v - Ca, H, R_i


@jacobian(ZeroAngularRate, "eci_left")
def _zero_rate_eci_left(m: ZeroAngularRate, core):
    """The gyros read b_g + C^T Omega_ie: with C = C_hat exp(phi), z = omega_mean - b_g_hat - w_hat
    = db_g + [w_hat]x phi (w_hat the Earth rate in the estimated body frame). Needs the gyro bias block 9:12."""
    w = core.C.T @ earth.OMEGA_IE_E
    H = np.zeros((3, core._n_states))
    H[:, 0:3] = lie.hat3(w)
    H[:, 9:12] = _I3
    return m.omega_mean_b - core.b_g - w, H, m.R_b


#: the noise [x the trace of the core's block] of a direction in which a gyro bias prior adds no information
_NO_INFORMATION = 1e12


@jacobian(GyroBiasPrior, "eci_left")
def _gyro_bias_eci_left(m: GyroBiasPrior, core):
    """db_g = b_g - b_g_hat observed (the bias block 9:12, additive) along the eigenvectors V of the information the
    prior adds, D = P^-1 - P0^-1 = V diag(lam) V^T (P0, b0 the core's block and bias): z = lam^-1 V^T (P^-1 b -
    P0^-1 b0) - V^T b0, H = V^T [0 I 0], N = diag(1 / lam), so that the posterior information is P^-1 and the mean b;
    a direction with lam <= 0 (the prior adds nothing there) is observed with z = 0 and a noise that leaves it as is."""
    P0, b0 = core.P[9:12, 9:12], np.asarray(core.b_g, float)
    Pi = np.linalg.inv(0.5 * (m.P_b_g_b + m.P_b_g_b.T))
    P0i = np.linalg.inv(0.5 * (P0 + P0.T))
    lam, V = np.linalg.eigh(0.5 * ((Pi - P0i) + (Pi - P0i).T))
    adds = lam > 1e-9 * float(np.max(np.linalg.eigvalsh(Pi)))
    lam_a = np.where(adds, lam, 1.0)
    z = np.where(adds, (V.T @ (Pi @ m.b_g_b - P0i @ b0)) / lam_a - V.T @ b0, 0.0)
    H = np.zeros((3, core._n_states))
    H[:, 9:12] = V.T
    return z, H, np.diag(np.where(adds, 1.0 / lam_a, _NO_INFORMATION * float(np.trace(P0))))


@jacobian(ZeroVelocity, "earth_left")
def _zupt_earth_left(m: ZeroVelocity, core):
    """earth_iekf's zero-velocity model (eqs. (50)-(55), its ``zupt_model``), isotropic noise."""
    z, H = core.zupt_model()
    return z, H, m.sigma_v_m_s ** 2 * _I3
