"""The scalar rotation conversions the node uses per output and per ground-truth message, and the session's truth
slerp, against scipy (the implementations they replace for cost: docs/nodes.md, "CPU share")."""

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from insalign_ros.nodes.conversions import quat_matrix, quat_xyzw
from insalign_ros.session.session import AlignmentSession, TruthSample


def _rotations(n=4000):
    R = Rotation.random(n, random_state=7)
    # the branch edges: identity, half turns about each axis, near-half turns, tiny angles
    extra = Rotation.from_rotvec(np.array([[0, 0, 0], [np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi],
                                           [np.pi - 1e-9, 0, 0], [1e-12, -1e-12, 1e-12], [2.0, 2.0, 1.0]], float))
    return Rotation.concatenate([R, extra])


def test_quat_xyzw_is_scipys_quaternion_same_sign():
    M = _rotations().as_matrix()
    q = np.array([quat_xyzw(C) for C in M])
    assert np.max(np.abs(q - Rotation.from_matrix(M).as_quat())) < 1e-15
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < 1e-15


def test_quat_xyzw_of_a_non_orthonormal_matrix_takes_scipys_nearest_rotation():
    C = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    C[0, 1] += 1e-3  # not a rotation: scipy projects it (SVD) before converting
    assert np.max(np.abs(quat_xyzw(C) - Rotation.from_matrix(C).as_quat())) < 1e-15


def test_quat_matrix_is_scipys_matrix_and_normalises():
    R = _rotations()
    Q = R.as_quat()
    M = np.array([quat_matrix(*q) for q in Q])
    assert np.max(np.abs(M - R.as_matrix())) < 2e-15
    M2 = np.array([quat_matrix(*(1.0007 * q)) for q in Q[:50]])  # a driver's slightly unnormalised quaternion
    assert np.max(np.abs(M2 - R[:50].as_matrix())) < 2e-15


def test_truth_slerp_between_two_poses_is_scipys_slerp():
    R = Rotation.random(2, random_state=3)
    Ca, Cb = R.as_matrix()
    Cb = (Rotation.from_matrix(Ca) * Rotation.from_rotvec([0.02, -0.05, 0.1])).as_matrix()  # 0.1 s apart
    s = AlignmentSession()
    s.push_truth(TruthSample(10.0, Ca))
    s.push_truth(TruthSample(10.1, Cb))
    ref = Slerp([10.0, 10.1], Rotation.from_matrix([Ca, Cb]))
    for t in (10.0, 10.013, 10.05, 10.0999, 10.1):
        got = s.outputs.truth_at(t)
        assert np.max(np.abs(got - ref([t]).as_matrix()[0])) < 1e-15, t
    assert s.outputs.truth_at(10.2) is None  # nothing after: no extrapolation


def test_diagnostics_window_and_quantiles_equal_a_deque_and_numpy_percentile():
    from collections import deque

    from insalign_ros.nodes.alignment_node import _quantiles
    from insalign_ros.session.session import Ring

    rng = np.random.default_rng(5)
    w, d = Ring(1000), deque(maxlen=1000)
    for m in (1, 7, 300, 0, 999, 1000, 2500, 3, 640):  # batches that wrap the ring, and one longer than it
        xs = rng.exponential(size=m)
        w.extend(xs)
        d.extend(xs)
        w.append(m + 0.5)
        d.append(m + 0.5)
        assert len(w) == len(d)
        assert np.array_equal(np.sort(w.view()), np.sort(np.asarray(d)))
        got = _quantiles(w.view(), (50.0, 99.0, 100.0))
        assert np.allclose(got, np.percentile(np.asarray(d), [50, 99, 100]), rtol=1e-14, atol=0), m


def test_a_fix_with_an_all_zero_covariance_takes_the_default_sigma():
    """A driver that fills APPROXIMATED (or any type) with zeros has said nothing about the covariance: the node uses
    ``gnss_sigma_m`` (as for UNKNOWN) instead of refusing the fix; a negative variance is still refused."""
    import numpy as np
    from sensor_msgs.msg import NavSatFix

    from insalign_ros.nodes.conversions import fix_from_msg

    m = NavSatFix()
    m.header.stamp.sec = 100
    m.latitude, m.longitude, m.altitude = 48.0, 11.0, 500.0
    m.status.status = NavSatFix().status.STATUS_FIX
    for kind in (NavSatFix.COVARIANCE_TYPE_APPROXIMATED, NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN,
                 NavSatFix.COVARIANCE_TYPE_UNKNOWN):
        m.position_covariance_type = kind
        m.position_covariance = [0.0] * 9
        fix, reason = fix_from_msg(m, 2.5)
        assert fix is not None, reason
        assert np.allclose(np.linalg.eigvalsh(fix.R_e), 2.5**2)  # isotropic: the same in ECEF
    m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
    m.position_covariance = [-1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    assert fix_from_msg(m, 2.5)[0] is None
