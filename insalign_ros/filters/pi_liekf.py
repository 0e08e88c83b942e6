"""PI-LIEKF (PI-LIEKF paper Alg. 2, eqs. (16)-(33)): the LIEKF with a proportional-integral innovation.

Per GNSS update k (our sign convention: :mod:`.liekf`):

* ``Z_p = X_hat^-1 Y - d`` restricted to the position block, ``= C^T (p_gps_i - p_hat)`` (eqs. (16), (29); the
  error-state prediction is zero after the reset of eq. (33));
* ``Z_PI = k_P Z_p + Z_I_{k-1}``, ``Z_I_k = Z_I_{k-1} + k_I T_s Z_p`` (eq. (29)); ``xi_hat = L_k Z_PI``
  (eq. (30)); covariance by eq. (31) (Joseph, unchanged: the covariance does not know about the PI loop);
* gains ``k_P, k_I`` from the LMI (:mod:`.lmi`), re-solved every ``lmi_resolve_every_updates`` updates and
  cached in between (A and H are state-independent; the LMI data change with the IMU input and L_k only).
  The cost per solve and the accuracy of caching are measured in docs/inmotion_cores.md.
* ``Z_I`` is clamped per axis at ``integral_clamp_m`` (anti-windup while a large initial attitude error makes the
  innovations meaningless as a bias signal).

``diagnostics()`` returns the latest LMI status, residual, solver time and whether the safe gains are in use.
"""

from __future__ import annotations

import numpy as np

from .config import PiLiekfConfig
from .liekf import Liekf


class PiLiekf(Liekf):
    """Proportional-integral LIEKF (9 states) with LMI gains."""

    name = "pi_liekf"
    config_class = PiLiekfConfig

    def __init__(self, config=None):
        super().__init__(config)
        self._solver = None
        self.lmi = None
        self.lmi_history: list = []

    def initialize(self, *args, **kwargs) -> None:
        super().initialize(*args, **kwargs)
        self.Z_I = np.zeros(3)
        self.k_P = np.eye(3)
        self.k_I = np.zeros((3, 3))
        self._n_updates = 0

    def _gain_solver(self):
        if self._solver is None:
            from .lmi import PiGainSolver, StructuredPiGainSolver

            cls = StructuredPiGainSolver if self.cfg.lmi_structure == "structured" else PiGainSolver
            self._solver = cls(9, 3, self.cfg.rho, self.cfg.lmi_solver, self.cfg.lmi_eps, self.cfg.safe_k_I_per_s)
        return self._solver

    def _correction(self, z, L, H, N):
        Ts = self.t_s - self._t_last_update
        if Ts <= 0.0:  # a fix at the initialisation time: no interval, plain Kalman correction
            return L @ z
        if self._n_updates % self.cfg.lmi_resolve_every_updates == 0:
            self.lmi = self._gain_solver().solve(self._Phi_since_update, H, L, Ts, self._P_prior)
            self.k_P, self.k_I = self.lmi.k_P, self.lmi.k_I
            self.lmi_history.append((self.t_s, self.lmi))
        self._n_updates += 1
        Z_PI = self.k_P @ z + self.Z_I
        self.Z_I = self.Z_I + self.k_I @ z * Ts
        c = self.cfg.integral_clamp_m
        if c > 0:
            self.Z_I = np.clip(self.Z_I, -c, c)
        return L @ Z_PI

    def diagnostics(self) -> dict:
        d = {"Z_I_m": self.Z_I.tolist() if self._init else None}
        if self.lmi is not None:
            r = self.lmi
            d.update(lmi_status=r.status, lmi_used_fallback=r.used_fallback, lmi_reason=r.reason,
                     lmi_residual_eq23=r.residual_eq23, lmi_max_eig=r.lmi_max_eig,
                     lmi_rate_margin_structured=r.rate_margin_structured,
                     lmi_spectral_radius_structured=r.spectral_radius_structured, lmi_solver=r.solver,
                     lmi_solve_time_s=r.solve_time_s, k_P=r.k_P.tolist(), k_I=r.k_I.tolist())
        return d
