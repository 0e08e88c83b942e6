"""A bank of yaw hypotheses (Gaussian-sum prior) around any in-motion core: alignment from an unknown heading.

Why: a 179 deg yaw error is not a Gaussian error in any parametrisation. A single invariant filter started
with it linearises the first GNSS updates around a nearly flipped attitude, its state-independent covariance
collapses anyway (yaw 3-sigma 3 deg after 10 s while the error is still 100 deg, ship scenario) and the run
ends tens of degrees off in some seeds (docs/inmotion_cores.md, "Unknown heading"). Every single filter of
the bank is started inside its convergence basin instead.

Model: the yaw prior N(0, sigma_yaw^2) about the initial guess (wrapped) is approximated by ``K`` components at
offsets ``2 pi k / K`` about the local Up axis, prior weights proportional to the wrapped normal density at the
offset, each with its own yaw sigma ``min(sigma_yaw, pi / K)`` (half the spacing). Every component is a full
core (LIEKF, PI-LIEKF, IEKF or EKF) run on the same data. Weights follow Bayes' rule with each component's
GNSS innovation likelihood ``N(z; 0, S)`` (position fixes and, where the core fuses them, GNSS velocities):

    log w_k += -0.5 (z_k^T S_k^-1 z_k + log det S_k)      (normalised after every fix)

Components whose weight falls below ``hypothesis_prune_weight`` (after ``hypothesis_min_updates`` fixes) are
dropped, and so is a component that has converged onto the same attitude as a better one (within
``hypothesis_merge_deg``; its weight goes to the survivor). With one component left the bank is a thin
pass-through and costs nothing extra.

Output: the estimate of the most probable component, with the spread of the live components added to its ENU
attitude covariance (``P_att_n + sum_k w_k d_k d_k^T``, ``d_k`` the rotation vector from the best attitude to
component k): the published 3-sigma cannot be small while another heading is still plausible, and the
status stays CONVERGING until one hypothesis is left.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, UpdateResult


def _rot_up(angle_rad: float) -> np.ndarray:
    """Rotation about the local Up (ENU z) axis."""
    return Rotation.from_rotvec([0.0, 0.0, angle_rad]).as_matrix()


class YawHypothesisBank(AlignmentCore):
    """K copies of one core at evenly spaced yaw offsets, weighted by their GNSS innovation likelihoods."""

    def __init__(self, core_class: type[AlignmentCore], cfg):
        self._core_class = core_class
        self.cfg = cfg
        self.K = int(cfg.yaw_hypotheses)
        if self.K < 2:
            raise ValueError(f"yaw_hypotheses: a bank needs >= 2 hypotheses, got {self.K}")
        c = core_class  # what each member declares, read from its class and configuration (none built here)
        self.name = c.name
        self.needs_motion = c.needs_motion
        self.convention, self.state_blocks, self.own_models = c.convention, c.state_blocks, c.own_models
        self.supports_backtracking = False
        self.att_index, self.vel_index, self.pos_index = c.att_index, c.vel_index, c.pos_index
        self.initial_sigmas = cfg.initial_sigmas
        self.hyps: list[AlignmentCore] = []
        self.offsets_rad: list[float] = []
        self.logw = np.zeros(0)
        self.n_updates = 0
        self.bank_counters = {"hypotheses_pruned": 0, "hypotheses_merged": 0}
        self.collapsed_at_s: float | None = None
        self._init = False

    # ------------------------------------------------------------------ life cycle
    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m) -> None:
        K = self.K
        P_att_n = np.asarray(P_att_n, float)
        sig_yaw = math.sqrt(max(P_att_n[2, 2], 0.0))
        sig_h = min(sig_yaw, math.pi / K) if sig_yaw > 0 else math.pi / K
        P_h = P_att_n.copy()
        if sig_yaw > 0:  # shrink the yaw variance, keep the correlations' shape
            s = sig_h / sig_yaw
            D = np.diag([1.0, 1.0, s])
            P_h = D @ P_att_n @ D
        else:
            P_h[2, 2] = sig_h * sig_h
        offs = [2.0 * math.pi * k / K for k in range(K)]
        offs = [math.remainder(o, 2.0 * math.pi) for o in offs]
        # wrapped-normal prior density at each offset (sigma_yaw = 0: all weight on the guess)
        if sig_yaw > 0:
            logw = np.array([math.log(sum(math.exp(-0.5 * ((o + 2 * math.pi * j) / sig_yaw) ** 2) for j in (-1, 0, 1))
                                      + 1e-300) for o in offs])
        else:
            logw = np.array([0.0] + [-np.inf] * (K - 1))
        self.close()  # a re-initialisation replaces the components
        self.hyps, self.offsets_rad = [], []
        for o, lw in zip(offs, logw):
            if not np.isfinite(lw):
                continue
            core = self._core_class(self.cfg)
            core.initialize(stamp_s, lat_rad, lon_rad, h_m, _rot_up(o) @ np.asarray(C_b_n, float), v_n, P_h,
                            sigma_v_m_s, sigma_p_m)
            self.hyps.append(core)
            self.offsets_rad.append(o)
        self.logw = logw[np.isfinite(logw)] - np.max(logw)
        self.n_updates = 0
        self.collapsed_at_s = None
        self._init = True

    @property
    def initialized(self) -> bool:
        return self._init

    @property
    def weights(self) -> np.ndarray:
        w = np.exp(self.logw - np.max(self.logw))
        return w / w.sum()

    @property
    def best(self) -> AlignmentCore:
        return self.hyps[int(np.argmax(self.logw))]

    @property
    def counters(self) -> dict:
        """The most probable component's counters plus the bank's own."""
        return {**self.best.counters, **self.bank_counters} if self.hyps else dict(self.bank_counters)

    @property
    def P(self):
        return self.best.P if self.hyps else None

    @property
    def busy(self) -> bool:
        return any(h.busy for h in self.hyps)

    def close(self) -> None:
        for h in self.hyps:
            h.close()

    def inflate_navigation(self, var_att_rad2: float, var_v_m2_s2: float, var_p_m2: float = 0.0,
                           var_bg_rad2_s2: float = 0.0, var_ba_m2_s4: float = 0.0) -> None:
        for h in self.hyps:
            h.inflate_navigation(var_att_rad2, var_v_m2_s2, var_p_m2, var_bg_rad2_s2, var_ba_m2_s4)

    # ------------------------------------------------------------------ events
    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        for h in self.hyps:
            h.propagate(t_s, omega_ib_b, f_ib_b, backward)

    def flush(self) -> None:
        for h in self.hyps:
            h.flush()

    def predict(self, meas) -> UpdateResult:
        """The prediction of the most probable hypothesis, once one is left; none while several live (their
        disagreement is what the weights resolve)."""
        if len(self.hyps) != 1:
            return UpdateResult(False, reason="several yaw hypotheses alive")
        return self.hyps[0].predict(meas)

    def update(self, meas) -> UpdateResult:
        """Every hypothesis fuses ``meas``; its innovation likelihood weighs the hypotheses (GNSS velocity: what the
        PX4 EKF-GSF yaw estimator uses alone) unless the model says it carries no heading evidence
        (``weighs_hypotheses`` False, the zero angular rate: the hypotheses differ only by the horizontal Earth
        rate, 10 deg/h, not worth the risk of a wrong noise model): then the weights do not move."""
        results = [h.update(meas) for h in self.hyps]
        if not meas.weighs_hypotheses:
            return results[int(np.argmax(self.logw))]
        return self._update(results)

    def _update(self, results: list[UpdateResult]) -> UpdateResult:
        """Weigh the components by their innovations; the result (accepted, innovation, NIS) is the one of the
        component that is the most probable after this update, the one the bank publishes from now on: the session's
        NIS tests (the flag's window, the divergence guard) see the innovations of the filter whose estimate and
        covariance they judge, not those of a heading the same fix has just made unlikely (a wrong component's NIS
        of 34 kept the flag's window of the survivor above its band for 10 s on park_drive)."""
        best = int(np.argmax(self.logw))
        if len(self.hyps) > 1:
            for k, r in enumerate(results):
                # accepted, or gated by this component's own NIS test (an implausible innovation is evidence
                # too); a fix rejected before any innovation (bad input) carries no S and changes nothing
                if r.S.size and np.isfinite(r.nis):
                    sign, logdet = np.linalg.slogdet(r.S)
                    self.logw[k] += -0.5 * (r.nis + (logdet if sign > 0 else 0.0))
            self.logw -= np.max(self.logw)
            best = int(np.argmax(self.logw))  # before pruning: the indices of ``results``
            if any(r.accepted for r in results):
                self.n_updates += 1
            self._prune()
        return results[best] if best < len(results) else results[0]

    def _prune(self) -> None:
        if self.n_updates < self.cfg.hypothesis_min_updates:
            return
        w = self.weights
        keep = [k for k in range(len(self.hyps)) if w[k] >= self.cfg.hypothesis_prune_weight]
        self.bank_counters["hypotheses_pruned"] += len(self.hyps) - len(keep)
        self._select(keep)
        # merge components that converged onto the same attitude as a more probable one
        order = list(np.argsort(-self.logw))
        keep, merged_into = [], {}
        for k in order:
            Ck = self.hyps[k].estimate().C_b_n
            for j in keep:
                Cj = self.hyps[j].estimate().C_b_n
                if np.degrees(np.linalg.norm(Rotation.from_matrix(Ck @ Cj.T).as_rotvec())) < self.cfg.hypothesis_merge_deg:
                    merged_into[k] = j
                    break
            else:
                keep.append(k)
        if merged_into:
            w = self.weights
            for k, j in merged_into.items():
                w[j] += w[k]
            self.bank_counters["hypotheses_merged"] += len(merged_into)
            self.logw = np.log(np.maximum(w, 1e-300))
            self._select(sorted(keep))
        if len(self.hyps) == 1 and self.collapsed_at_s is None:
            self.collapsed_at_s = float(self.hyps[0].estimate().stamp_s)

    def _select(self, keep: list[int]) -> None:
        if len(keep) == len(self.hyps):
            return
        for k in set(range(len(self.hyps))) - set(keep):
            self.hyps[k].close()
        self.hyps = [self.hyps[k] for k in keep]
        self.offsets_rad = [self.offsets_rad[k] for k in keep]
        self.logw = self.logw[keep] - np.max(self.logw[keep])

    # ------------------------------------------------------------------ output
    def estimate(self) -> AlignmentEstimate:
        if not self._init:
            raise RuntimeError("estimate() before initialize()")
        b = int(np.argmax(self.logw))
        est = self.hyps[b].estimate()
        if len(self.hyps) == 1:
            return est
        return self._mixed(b, est, [self.hyps[k].estimate() for k in range(len(self.hyps)) if k != b])

    def _estimates_along(self, t_s, omega_ib_b, f_ib_b, ends) -> list[AlignmentEstimate]:
        """Each hypothesis's own estimates (``propagate(..., estimates_at=ends)``), mixed per output as :meth:`estimate` mixes them."""
        if not self._init or not self.hyps:
            return super()._estimates_along(t_s, omega_ib_b, f_ib_b, ends)
        per = [h.propagate(t_s, omega_ib_b, f_ib_b, estimates_at=ends) for h in self.hyps]
        if len(per) == 1:
            return per[0]
        b = int(np.argmax(self.logw))
        return [self._mixed(b, per[b][s], [per[k][s] for k in range(len(per)) if k != b]) for s in range(len(ends))]

    def _mixed(self, b: int, est: AlignmentEstimate, other_ests: list) -> AlignmentEstimate:
        """The estimate of the most probable hypothesis ``b`` with the weighted spread of the others' attitudes."""
        w = self.weights
        others = [k for k in range(len(self.hyps)) if k != b]
        # one scipy call for all the hypotheses (the same rotation vectors as one call each)
        D = Rotation.from_matrix(np.array([e.C_b_n @ est.C_b_n.T for e in other_ests])).as_rotvec()
        spread = np.zeros((3, 3))
        for d, k in zip(D, others):
            spread += w[k] * np.outer(d, d)
        est.P_att_n = est.P_att_n + spread
        sig_yaw3 = 3.0 * math.degrees(math.sqrt(max(est.P_att_n[2, 2], 0.0)))
        est.status = AlignmentStatus.CONVERGING
        est.reason = (f"{len(self.hyps)} yaw hypotheses alive (best weight {w[b]:.3f}); "
                      f"3-sigma yaw {sig_yaw3:.2f} deg")
        return est

    def diagnostics(self) -> dict:
        d = dict(self.best.diagnostics())
        d.update(yaw_hypotheses_alive=len(self.hyps), yaw_hypothesis_weights=self.weights.round(4).tolist(),
                 yaw_hypothesis_offsets_deg=[round(math.degrees(o), 1) for o in self.offsets_rad],
                 yaw_hypotheses_collapsed_at_s=self.collapsed_at_s, **self.bank_counters)
        return d
