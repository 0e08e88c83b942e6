"""Vehicle measurement models (issue 25): the non-holonomic constraint of a land vehicle and a dual-antenna GNSS
heading, as models of filters/measurements.py with Jacobians for the ECI conventions ``eci_left`` (liekf, pi_liekf,
iekf and their yaw banks) and ``eci_ekf`` (ekf). No core knows them: ``core.update(NonHolonomic(...))`` fuses them
in every core whose convention they support (``type(m) in core.accepts``).

Constructors:

* ``NonHolonomic(stamp_s, sigma_lateral_m_s, sigma_vertical_m_s, C_b_v=I)``: the vehicle frame's lateral (y) and
  vertical (z) velocity relative to Earth are zero, 1-sigmas [m/s] covering the side-slip and the suspension;
  ``C_b_v`` (3x3) maps IMU body FLU vectors into the vehicle frame FLU (the IMU mounting, x forward along the
  wheels). The velocity is the IMU's (the lever arm from the IMU to the rear axle is neglected: omega x l, < 0.1 m/s
  for 1 m at 5 deg/s, inside a side-slip sigma).
* ``GnssHeading(stamp_s, yaw_rad, sigma_yaw_rad, baseline_b=(1, 0, 0))``: the yaw of the dual-antenna baseline in
  ENU [rad] (from East, counter-clockwise, REP 103: a driver's heading from North clockwise converts as
  ``yaw = pi/2 - heading``), its 1-sigma [rad], and the baseline's direction in the body frame (FLU, any length;
  primary -> secondary antenna). The local level's dependence on the position error (~1.6e-7 rad/m) is neglected.
* ``WheelSpeed(stamp_s, speed_m_s, var_m2_s2, scale=1, sigma_scale=0, C_b_v=I)``: the wheel odometry's speed along
  the vehicle's x axis [m/s] and its variance [m^2/s^2], read as ``h = scale * e_x^T C_b_v C^T u`` (u the velocity
  relative to Earth, as for the constraint above): the wheels read the forward speed times a scale factor (tyre
  radius, pressure, load). The cores keep no scale state: the session estimates it (session/wheel_scale.py) and
  passes its estimate ``scale`` and 1-sigma ``sigma_scale`` (a fraction); the noise is
  ``var + (sigma_scale * speed / scale)^2`` (the scale's uncertainty as measurement noise). The scale's error is
  one bias shared by every sample: a caller fusing at a high rate must inflate ``sigma_scale`` so that the bias is not
  averaged down (the session counts it once per 10 s of data: session/fusion.py, WHEEL_SCALE_MEMORY_S). The lever
  arm from the IMU to the wheels is neglected, as for the constraint.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import earth, lie
from .measurements import Measurement, jacobian

_I3 = np.eye(3)


class NonHolonomic(Measurement):
    """Lateral and vertical velocity of the vehicle frame ~ 0 (a land vehicle neither slides nor jumps).
    ``sigma_vertical_m_s`` = inf leaves the vertical row out (the lateral constraint alone)."""

    counter = "nhc"
    label = "non-holonomic constraint"
    fading = False

    def __init__(self, stamp_s: float, sigma_lateral_m_s: float, sigma_vertical_m_s: float, C_b_v=None):
        self.stamp_s = float(stamp_s)
        self.sigma_lateral_m_s = float(sigma_lateral_m_s)
        self.sigma_vertical_m_s = float(sigma_vertical_m_s)
        self.C_b_v = _I3.copy() if C_b_v is None else np.asarray(C_b_v, float)

    @property
    def rows(self) -> list:
        """The rows of the vehicle frame constrained: y (lateral), and z (vertical) unless its sigma is inf."""
        return [1] if math.isinf(self.sigma_vertical_m_s) else [1, 2]

    def check(self) -> str:
        s = (self.sigma_lateral_m_s, self.sigma_vertical_m_s)
        if not (math.isfinite(s[0]) and s[0] > 0 and s[1] > 0 and not math.isnan(s[1])):
            return f"sigmas {s} must be > 0 (lateral finite; vertical inf: not constrained)"
        C = self.C_b_v
        if C.shape != (3, 3) or not np.all(np.isfinite(C)) or np.abs(C @ C.T - _I3).max() > 1e-6:
            return "C_b_v must be a 3x3 rotation matrix"
        return ""

    def noise(self) -> np.ndarray:
        return np.diag([self.sigma_lateral_m_s ** 2, self.sigma_vertical_m_s ** 2][:len(self.rows)])


def _earth_relative_velocity_i(core) -> tuple[np.ndarray, np.ndarray]:
    """(u_i, Omega_i): the velocity relative to Earth in ECI, u = v_i - Omega x p_i [m/s], and the Earth rate
    vector in ECI [rad/s] (the ECI z axis is the Earth's)."""
    W = earth.OMEGA_IE_E  # (0, 0, omega_ie): the same in ECI
    return core.v - np.cross(W, core.p), W


@jacobian(NonHolonomic, "eci_left")
def _nhc_eci_left(m: NonHolonomic, core):
    """h = E C_b_v C^T u, E the (y, z) rows (y alone without the vertical). With C = C_hat exp(phi), v = v_hat + C_hat nu, p = p_hat + C_hat rho:
    h = h_hat + E C_b_v [b_x phi + nu - w_x rho], b = C_hat^T u_hat, w = C_hat^T Omega."""
    u, W = _earth_relative_velocity_i(core)
    Ct = core.C.T
    b, w = Ct @ u, Ct @ W
    E = m.C_b_v[m.rows]
    H = np.zeros((len(E), core._n_states))
    H[:, 0:3] = E @ lie.hat3(b)
    H[:, 3:6] = E
    H[:, 6:9] = -E @ lie.hat3(w)
    return -(E @ b), H, m.noise()


@jacobian(NonHolonomic, "eci_ekf")
def _nhc_eci_ekf(m: NonHolonomic, core):
    """With C = exp(psi_x) C_hat, v = v_hat + dv, p = p_hat + dp: h = h_hat + E C_b_v C_hat^T [u_x psi + dv - Omega_x dp]."""
    u, W = _earth_relative_velocity_i(core)
    A = m.C_b_v[m.rows] @ core.C.T
    H = np.zeros((len(A), core._n_states))
    H[:, 0:3] = A @ lie.hat3(u)
    H[:, 3:6] = A
    H[:, 6:9] = -A @ lie.hat3(W)
    return -(A @ u), H, m.noise()


class GnssHeading(Measurement):
    """Dual-antenna (moving-base) GNSS heading: the baseline's yaw in ENU [rad] with its 1-sigma [rad]."""

    counter = "gnss_heading"
    label = "GNSS heading"
    fading = False

    def __init__(self, stamp_s: float, yaw_rad: float, sigma_yaw_rad: float, baseline_b=(1.0, 0.0, 0.0)):
        self.stamp_s = float(stamp_s)
        self.yaw_rad = float(yaw_rad)
        self.sigma_yaw_rad = float(sigma_yaw_rad)
        self.baseline_b = np.asarray(baseline_b, float)

    def check(self) -> str:
        if not (math.isfinite(self.yaw_rad) and math.isfinite(self.sigma_yaw_rad) and self.sigma_yaw_rad > 0):
            return f"yaw {self.yaw_rad!r} and sigma {self.sigma_yaw_rad!r} must be finite, sigma > 0"
        b = self.baseline_b
        if b.shape != (3,) or not np.all(np.isfinite(b)) or not np.linalg.norm(b) > 0:
            return "baseline_b must be a finite non-zero 3-vector"
        return ""


def _n_from_i(core) -> np.ndarray:
    """C_i_n: ECI -> local ENU at the estimated position."""
    Cei = earth.C_e_i(core.t_s, core.t0_s)
    lat, lon, _ = earth.ecef_to_geodetic(Cei.T @ core.p)
    return earth.C_n_e(lat, lon).T @ Cei.T


#: finite-difference step of the heading's second derivative in the attitude error [rad]
_HESS_STEP_RAD = 1e-3


def _yaw_terms(m: GnssHeading, b_n: np.ndarray, D: np.ndarray, core, b_of=None):
    """z = wrap(yaw_m - atan2(b_n_y, b_n_x)), H = g^T D on the attitude block, g = d yaw / d b_n.

    R = sigma^2 + 1/2 tr(M P M P): the variance of the heading's second-order term over the attitude error (M its
    Hessian in the error, P the attitude block; the second-order Gaussian filter's measurement noise). A baseline's
    azimuth moves with the tilt only to second order, so a heading of a few tenths of a degree fused while the level is
    tens of degrees uncertain (a yaw bank just after a hand-over on a ship) is worth what that term says, not its
    sigma: linearised, it made the IEKF certain of a level 12 deg off. ``b_of(phi)``: b_n at the error ``phi``."""
    r2 = b_n[0] ** 2 + b_n[1] ** 2
    if not r2 > 1e-12 * float(b_n @ b_n):  # a vertical baseline: no yaw
        raise ValueError("GNSS heading: the baseline is vertical in the estimated attitude")
    g = np.array([-b_n[1], b_n[0], 0.0]) / r2
    H = np.zeros((1, core._n_states))
    H[0, 0:3] = g @ D
    z = np.array([math.remainder(m.yaw_rad - math.atan2(b_n[1], b_n[0]), 2.0 * math.pi)])
    var = m.sigma_yaw_rad ** 2
    if b_of is not None:
        P = np.asarray(core.P, float)[0:3, 0:3]
        # an error of more than 90 deg is not a second-order term (a yaw left unknown: 1e4 deg): capped there
        f = np.minimum(1.0, (0.5 * math.pi) / np.sqrt(np.maximum(np.diag(P), 1e-300)))
        P = P * np.outer(f, f)
        M = _yaw_hessian(b_of)
        MP = M @ P
        var += 0.5 * float(np.trace(MP @ MP))
    return z, H, np.array([[var]])


def _yaw_hessian(b_of) -> np.ndarray:
    """Hessian (3x3) of atan2(b_y, b_x) of ``b_of(phi)`` at phi = 0, by central differences (step _HESS_STEP_RAD)."""
    h = _HESS_STEP_RAD
    E = np.eye(3) * h

    def yaw(phi):
        b = b_of(phi)
        return math.atan2(b[1], b[0])

    y0 = yaw(np.zeros(3))
    M = np.empty((3, 3))
    for i in range(3):
        M[i, i] = math.remainder(yaw(E[i]) - 2.0 * y0 + yaw(-E[i]), 2.0 * math.pi) / (h * h)
        for j in range(i + 1, 3):
            d = (yaw(E[i] + E[j]) - yaw(E[i] - E[j]) - yaw(E[j] - E[i]) + yaw(-E[i] - E[j]))
            M[i, j] = M[j, i] = math.remainder(d, 2.0 * math.pi) / (4.0 * h * h)
    return M


@jacobian(GnssHeading, "eci_left")
def _heading_eci_left(m: GnssHeading, core):
    """b_n = C_i_n C_hat exp(phi) b_b = b_n_hat - C_i_n C_hat (b_b)_x phi."""
    A = _n_from_i(core) @ core.C
    return _yaw_terms(m, A @ m.baseline_b, -A @ lie.hat3(m.baseline_b), core,
                      lambda phi: A @ lie.so3_exp(phi) @ m.baseline_b)


@jacobian(GnssHeading, "eci_ekf")
def _heading_eci_ekf(m: GnssHeading, core):
    """b_n = C_i_n exp(psi_x) C_hat b_b = b_n_hat - C_i_n (C_hat b_b)_x psi."""
    Cin = _n_from_i(core)
    c = core.C @ m.baseline_b
    return _yaw_terms(m, Cin @ c, -Cin @ lie.hat3(c), core, lambda psi: Cin @ lie.so3_exp(psi) @ c)


class WheelSpeed(Measurement):
    """Wheel odometry: the speed along the vehicle's x axis [m/s] (negative: reversing) with its variance
    [m^2/s^2], read as ``scale`` times the vehicle-frame forward velocity relative to Earth. Own NIS gate: chi-square
    1 dof, p = 1e-3 (a wheel that slips or locks is rejected); no fading."""

    counter = "wheel_speed"
    label = "wheel speed"
    fading = False
    nis_gate = 10.83

    def __init__(self, stamp_s: float, speed_m_s: float, var_m2_s2: float, scale: float = 1.0,
                 sigma_scale: float = 0.0, C_b_v=None):
        self.stamp_s = float(stamp_s)
        self.speed_m_s = float(speed_m_s)
        self.var_m2_s2 = float(var_m2_s2)
        self.scale = float(scale)
        self.sigma_scale = float(sigma_scale)
        self.C_b_v = _I3.copy() if C_b_v is None else np.asarray(C_b_v, float)

    def check(self) -> str:
        if not (math.isfinite(self.speed_m_s) and math.isfinite(self.var_m2_s2) and self.var_m2_s2 > 0):
            return f"speed {self.speed_m_s!r} and variance {self.var_m2_s2!r} must be finite, variance > 0"
        if not (math.isfinite(self.scale) and self.scale > 0 and math.isfinite(self.sigma_scale)
                and self.sigma_scale >= 0):
            return f"scale {self.scale!r} must be finite and > 0, sigma_scale {self.sigma_scale!r} finite and >= 0"
        C = self.C_b_v
        if C.shape != (3, 3) or not np.all(np.isfinite(C)) or np.abs(C @ C.T - _I3).max() > 1e-6:
            return "C_b_v must be a 3x3 rotation matrix"
        return ""

    def noise(self) -> np.ndarray:
        """The wheel's variance plus the scale's: (sigma_scale * speed / scale)^2 [m^2/s^2]."""
        return np.array([[self.var_m2_s2 + (self.sigma_scale * self.speed_m_s / self.scale) ** 2]])


@jacobian(WheelSpeed, "eci_left")
def _wheel_eci_left(m: WheelSpeed, core):
    """h = k e_x^T C_b_v C^T u (k the scale); with C = C_hat exp(phi), v = v_hat + C_hat nu, p = p_hat + C_hat rho:
    h = h_hat + k e_x^T C_b_v [b_x phi + nu - w_x rho], b = C_hat^T u_hat, w = C_hat^T Omega (as the constraint)."""
    u, W = _earth_relative_velocity_i(core)
    Ct = core.C.T
    b, w = Ct @ u, Ct @ W
    e = m.scale * m.C_b_v[0]
    H = np.zeros((1, core._n_states))
    H[0, 0:3] = e @ lie.hat3(b)
    H[0, 3:6] = e
    H[0, 6:9] = -e @ lie.hat3(w)
    return np.array([m.speed_m_s - e @ b]), H, m.noise()


@jacobian(WheelSpeed, "eci_ekf")
def _wheel_eci_ekf(m: WheelSpeed, core):
    """With C = exp(psi_x) C_hat, v = v_hat + dv, p = p_hat + dp: h = h_hat + k e_x^T C_b_v C_hat^T [u_x psi + dv -
    Omega_x dp]."""
    u, W = _earth_relative_velocity_i(core)
    a = m.scale * (m.C_b_v[0] @ core.C.T)
    H = np.zeros((1, core._n_states))
    H[0, 0:3] = a @ lie.hat3(u)
    H[0, 3:6] = a
    H[0, 6:9] = -a @ lie.hat3(W)
    return np.array([m.speed_m_s - a @ u]), H, m.noise()
