"""Metrics: closed-form cases for RMSE, time-below, steady state, NEES band and the NEES of evaluate()."""

import numpy as np
from scipy.spatial.transform import Rotation

from insalign_ros.eval import metrics as MT
from insalign_ros.filters.base import AlignmentEstimate


def test_rmse_time_below_steady_state():
    t = np.arange(0.0, 100.0, 1.0)
    err = np.zeros((100, 3))
    err[:, 2] = np.where(t < 30, 10.0, 0.5)
    err[50, 2] = -1.5  # a late excursion above 1 deg resets the "stays below" time
    assert MT.time_below_s(t, err[:, 2], 1.0) == 51.0
    assert np.isnan(MT.time_below_s(t, np.r_[err[:-1, 2], 2.0], 1.0))
    assert np.allclose(MT.rmse_deg(err, t, 60.0), [0, 0, 0.5])
    assert np.allclose(MT.steady_state_deg(t, err, 10.0), [0, 0, 0.5])


def test_nees_band_and_evaluate_nees():
    lo, hi = MT.nees_band(1)
    assert abs(lo - 0.2158) < 1e-3 and abs(hi - 9.3484) < 1e-3
    lo10, hi10 = MT.nees_band(10)
    assert lo10 > lo and hi10 < hi
    rng = np.random.default_rng(0)
    P = np.diag(np.radians([1.0, 2.0, 3.0]) ** 2)
    C_ref = Rotation.from_euler("ZYX", [0.7, 0.05, -0.02]).as_matrix()
    ests, nees_direct = [], []
    for k in range(2000):
        psi = np.linalg.cholesky(P) @ rng.normal(size=3)
        C_est = Rotation.from_rotvec(-psi).as_matrix() @ C_ref  # C_ref = exp(psi) C_est
        ests.append(AlignmentEstimate(float(k), C_est, np.zeros(3), 0, 0, 0, P, P, ()))
        nees_direct.append(psi @ np.linalg.solve(P, psi))
    r = MT.evaluate("x", ests, np.arange(2000.0), np.repeat(C_ref[None], 2000, 0), 0.0)
    assert np.allclose(r.nees, nees_direct, rtol=1e-6)
    assert abs(np.mean(r.nees) - 3.0) < 0.25


def test_the_event_list_names_every_restart_and_flag_move_and_survives_the_restart():
    """The offline CSV's ``event`` column and the JSON's ``events``: a flag rise, the guard's drop and a restart
    (FAULT with its reason), in order, each on the output row at or after its time; the session keeps the list
    across the restart (it used to start again empty)."""
    from types import SimpleNamespace

    from insalign_ros.session.offline import event_column, events_of

    sess = SimpleNamespace(flag_changes=[(10.0, True, "criteria hold"),
                                         (20.05, False, "inconsistent innovations: CUSUM 41 above 40"),
                                         (30.0, False, "fault (divergence: mean NIS 1e5); re-initialising")])
    ev = events_of(sess)
    assert [e["event"] for e in ev] == ["flag_raised", "flag_lowered", "restart"]
    assert ev[2]["t_s"] == 30.0 and "mean NIS" in ev[2]["reason"]
    col = event_column(np.arange(0.0, 40.0, 0.1), ev)
    assert col[100].startswith("flag_raised") and col[201].startswith("flag_lowered") and col[300].startswith("restart")
    assert sum(bool(c) for c in col) == 3


def test_a_restart_keeps_the_event_list():
    from insalign_ros.session.config import SessionConfig
    from insalign_ros.session.session import AlignmentSession

    s = AlignmentSession(SessionConfig.from_dict({"core": "iekf"}))
    try:
        s.flag_changes.append((5.0, True, "criteria hold"))
        s._restart("divergence: test")
        assert [c[0] for c in s.flag_changes] == [5.0, 0.0] and s.flag_changes[1][2].startswith("fault (")
    finally:
        s.close()
