"""The static cores' runs in one compiled call: ``StaticZuptCore.propagate(..., estimates_at, updates)`` with the
session's zero-velocity updates inside a run of samples (:func:`static_kernels.static_run_nb`), the numbers of the
segment-by-segment path (test/test_outputs_bulk.py)."""

from __future__ import annotations

import math

import numpy as np

from .base import UpdateResult
from .checks import usable_imu_arrays
from .measurements import ZeroVelocity
from .static_kernels import _M0, static_run_nb


def run_with_updates(core, t_s, omega_ib_b, f_ib_b, ends: list, updates, out: list, inputs) -> bool:
    """``core._updates_along`` in one compiled call (the flushes, the zero-velocity updates of ``_zupt_compiled`` and
    the estimates' states, at the rows the segment-by-segment path makes them); the results and estimates appended
    to ``out`` (``inputs``: the core's StaticModelInputs class, for its last step's inputs). False (nothing done) unless the run allows it: initialised, past the azimuth bootstrap, usable rows,
    zero-velocity updates only, one per row, the compiled step (``_fused_zupt``)."""
    models = [u[1] for u in updates]
    arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, core.t_s) if core._init and not core._boot else None
    if (arr is None or not type(core).__dict__.get("_fused_zupt", False) or core._model_error_prime() is not None
            or any(type(z) is not ZeroVelocity or z.check() for z in models)):
        return False
    t, w, f, dt = arr
    DT0, W0, F0 = core._buf.take() if core._buf.n else (np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
    n0 = DT0.shape[0]
    DT, W, F = (np.concatenate((DT0, dt)), np.concatenate((W0, w)), np.concatenate((F0, f))) if n0 else (dt, w, f)
    upd_rows, est_rows = [u[0] for u in updates], set(ends)
    upd_set = set(upd_rows)
    if len(upd_set) != len(upd_rows):
        raise ValueError("static cores: one zero-velocity update per row")
    rows = sorted(upd_set | est_rows)
    ev_row = np.array(rows, np.int64) + n0
    ev_upd = np.array([r in upd_set for r in rows])
    ev_est = np.array([r in est_rows for r in rows])
    m, nu, ne, n = core.mech, len(upd_rows), len(est_rows), core.x.shape[0]
    C, v = np.array(m.C_b_n, dtype=float), np.array(m.v_n, dtype=float)
    acc, gyro = np.array(m.acc_correction_b, dtype=float), np.array(m.gyro_correction_b, dtype=float)
    f_lp = np.zeros(3) if core._f_lp_ned is None else np.array(core._f_lp_ned, dtype=float)
    st = np.array([core._dt_acc, float(core._f_lp_ned is not None), core.cfg.specific_force_lowpass_s])
    oc_w_h = core._oc_w_h()
    N_k = np.zeros(n) if oc_w_h <= 0 else np.array(
        core._N_prev if core._N_prev is not None else core._nullspace(core.x[4]), dtype=float)
    p, re, qm, m_rate = core._pkf_args()
    zargs = np.array([m.lat_rad, core.r_m, float(core.n_bias > 0), oc_w_h, p, re,
                      math.radians(core.cfg.azimuth_feedback_sigma_deg)])
    P = np.array(core.P, dtype=float)
    INNOV, SS, NIS = np.empty((nu, 2)), np.empty((nu, 2, 2)), np.empty(nu)
    SX, SP, SC, SV, SA, SG = (np.empty((ne, n)), np.empty((ne, n, n)), np.empty((ne, 3, 3)), np.empty((ne, 3)),
                              np.empty((ne, 3)), np.empty((ne, 3)))
    mech = (C, v, gyro, acc, np.asarray(m.omega_ie_n, float), np.asarray(m.g_n, float), core._f_sum_n,
            np.array([m.R_N_m, m.R_E_m, m.tan_lat]))
    k0 = static_run_nb(DT, W, F, ev_row, ev_upd, ev_est, mech, (f_lp, st), core.x, P, zargs, _M0,
                       core._q_rate(), N_k, np.array([z.sigma_v_m_s ** 2 for z in models]), qm, m_rate,
                       INNOV, SS, NIS, SX, SP, SC, SV, SA, SG)
    core.P, core._dt_acc = P, float(st[0])
    m.C_b_n, m.v_n, m.acc_correction_b, m.gyro_correction_b = C, v, acc, gyro
    if nu:
        core._f_lp_ned = f_lp
        core._u_last = inputs(f_lp, m.lat_rad, core.r_m)
        core.t_last_update_s = float(models[-1].stamp_s)
        if oc_w_h > 0:
            core._N_prev = N_k
        if p > 0:
            core.m_rate = m_rate
    iu = ie = 0
    for r, is_u, is_e in zip(ev_row.tolist(), ev_upd.tolist(), ev_est.tolist()):
        if is_u:
            out.append(UpdateResult(True, innovation=INNOV[iu], S=SS[iu], nis=float(NIS[iu])))
            iu += 1
        if is_e:
            out.append(core._estimate_of(float(t[r - n0]), SX[ie], SP[ie], SC[ie], SV[ie], SG[ie], SA[ie], True))
            ie += 1
    if k0 < DT.shape[0]:
        core._buf.add_block(DT[k0:], W[k0:], F[k0:])
    core.t_s = float(t[-1])
    return True
