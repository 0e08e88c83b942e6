"""Earth-frame (ECEF) strapdown mechanization with the auxiliary velocity, forward and inverse.

Inverse-alignment paper (Liu et al. 2025, "group affine inverse alignment"), eqs. (21)-(31):

* attitude ``C_b_e`` (body FLU -> ECEF), eq. (21):  ``dC/dt = C (omega_ib_b)_x - (omega_ie_e)_x C``
* auxiliary velocity ``vbar_e = v_e + omega_ie_e x p_e`` (eq. (23)), eq. (22):
  ``dvbar/dt = C f_ib_b - omega_ie_e x vbar_e + gbar_e`` with ``gbar_e = g_e + omega_ie x (omega_ie x p_e)``
  (eq. (24)), i.e. ``gbar_e`` is the pure *gravitation* (earth.gravitation_e), the centrifugal part of gravity
  cancels;
* position, eq. (26): ``dp/dt = vbar_e - omega_ie_e x p_e``.

Exact relation to the ECI mechanization (the implementation, filters/earth_iekf.py, uses it; its numpy form, one step
forward and back, is test/oracles.py ``propagate_e`` / ``propagate_e_inverse``): with an ECI epoch at the start of a
step, ``(C_b_e, vbar_e, p_e) = C_i_e(t) (C_b_i, v_i, p_i)``, because ``v_i = C_e_i (v_e + omega x p_e)``. A step of
the Earth-frame mechanization is therefore one step of core/mechanization.py's ECI scheme with the epoch at the step
start, followed by the rotation ``C_i_e(dt) = exp(-omega_ie_e dt)``. This keeps the IMU-sample timing convention of
core/mechanization.py (sample k is the average over (t_{k-1}, t_k]) and makes the simulators' data (discrete-
consistent with that scheme) integrate to the truth in this frame too. The inverse step (eqs. (6)-(10) of the paper,
in the Earth frame) undoes the rotation and inverts the ECI step, so forward then inverse returns to the start
to rounding error (test/test_mechanization_e.py).

The 5x5 element ``X = [[C_b_e, vbar_e, p_e], [0, 1, 0], [0, 0, 1]]`` (eq. (32)) obeys a group-affine vector field
(eq. (33)) when ``gbar`` is frozen over a step; test/oracles.py ``vector_field_e`` gives it for the test of the identity
``f(AB) = f(A) B + A f(B) - A f(I) B`` (docs/backtracking.md has the proof).
"""

from __future__ import annotations

import numpy as np

from . import earth

OMEGA_IE_E = earth.OMEGA_IE_E


def vbar_from_v_e(v_e: np.ndarray, p_e: np.ndarray) -> np.ndarray:
    """Auxiliary velocity, eq. (23): vbar_e = v_e + omega_ie_e x p_e [m/s]."""
    return np.asarray(v_e, float) + np.cross(OMEGA_IE_E, p_e)


def v_e_from_vbar(vbar_e: np.ndarray, p_e: np.ndarray) -> np.ndarray:
    """ECEF velocity relative to the Earth [m/s] from the auxiliary velocity."""
    return np.asarray(vbar_e, float) - np.cross(OMEGA_IE_E, p_e)
