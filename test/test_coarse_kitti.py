"""Coarse alignment on real data: KITTI 2011_09_28_drive_0016 (fully stationary, OXTS RT3003 10 Hz outputs, 19 s) and
the stationary first 27 s of 2011_09_26_drive_0057 (it drives off at ~29 s).

Skips with the reason when ../shared/data is absent (the data-free tests cover the code: test_static_short.py).
Physics: level from 19 s of specific force must agree with the RT3003's own roll/pitch to 0.05 deg (its spec is
0.03 deg); the heading cannot be given: the 10 Hz gyro outputs have 0.02 deg/s per-sample noise -> 5.3 deg/h on
the 19 s mean against 9.9 deg/h of horizontal Earth rate at 49 deg -> ~33 deg azimuth sigma, above the 30 deg limit."""

import math
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from insalign_ros.core import earth
from insalign_ros.filters.base import AlignmentStatus
from insalign_ros.filters.coarse import NO_HEADING, CoarseAlignment, CoarseConfig
from insalign_ros.io.datasets import shared_data_dir

DATA = (shared_data_dir(__file__) or Path("../shared/data")) / "kitti_raw_oxts_sync"
DRIVE = DATA / "2011_09_28_drive_0016_oxts"
#: drive -> rows of its stationary part (0057: speed < 0.02 m/s until row ~280, driving from ~290)
STATIC_ROWS = {"2011_09_28_drive_0016": None, "2011_09_26_drive_0057": 270}
#: RT3003 10 Hz outputs: 0.02 deg/s per sample -> ARW 0.02/sqrt(10 Hz) deg/sqrt(s) = 0.38 deg/sqrt(h)
RT3003 = {"gyro_arw_deg_sqrt_h": 0.38, "gyro_bias_deg_h": 2.0, "acc_bias_mg": 0.1, "min_window_s": 10.0}


def _load(path):
    if not (path / "timestamps.txt").exists():
        pytest.skip(f"real data not available: {path} is absent (read-only shared data, never copied into the repo)")
    ts = [datetime.strptime(s.strip()[:26], "%Y-%m-%d %H:%M:%S.%f")
          for s in (path / "timestamps.txt").read_text().splitlines() if s.strip()]
    t = np.array([(x - ts[0]).total_seconds() for x in ts])
    rows = np.array([np.loadtxt(f) for f in sorted((path / "data").glob("*.txt"))])
    return t, rows


@pytest.fixture(scope="module")
def drive():
    return _load(DRIVE)


def _run(t, rows, cfg):
    core = CoarseAlignment(cfg)
    lat, lon, h = math.radians(rows[0, 0]), math.radians(rows[0, 1]), rows[0, 2]
    core.initialize(t[0], lat, lon, h, np.eye(3), np.zeros(3), np.eye(3), 0.01, 1.0)
    for k in range(1, len(t)):  # sample k: the RT3003's 10 Hz output, taken as the mean over (t_{k-1}, t_k]
        core.propagate([float(t[k])], [rows[k, 17:20]], [rows[k, 11:14]])
    return core.estimate()


def test_kitti_stationary_level_and_no_heading(drive):
    t, rows = drive
    cfg = CoarseConfig.from_dict(RT3003)
    e = _run(t, rows, cfg)
    ref = rows[:, 3:6].mean(0)  # OXTS roll, pitch, yaw [rad] (REP 103 / FLU, yaw from East CCW)
    rpy = earth.rpy_from_C_b_n(e.C_b_n)
    assert np.all(np.abs(np.degrees(rpy[:2] - ref[:2])) < 0.05), (np.degrees(rpy), np.degrees(ref))
    assert e.status is AlignmentStatus.WAITING_FOR_DATA and NO_HEADING in e.reason, e.reason
    # allowing a 60 deg sigma, it gives a heading, and the OXTS yaw is inside its 2-sigma
    e2 = _run(t, rows, CoarseConfig.from_dict({**cfg.to_dict(), "max_azimuth_sigma_deg": 60.0}))
    assert e2.status is AlignmentStatus.ALIGNED
    dyaw = float(earth.wrap_angle_rad(earth.rpy_from_C_b_n(e2.C_b_n)[2] - ref[2]))
    assert abs(dyaw) < 2 * math.sqrt(e2.P_att_n[2, 2]), (math.degrees(dyaw), math.degrees(math.sqrt(e2.P_att_n[2, 2])))


@pytest.mark.parametrize("name", sorted(STATIC_ROWS))
@pytest.mark.parametrize("method", ["average", "inertial"])
def test_kitti_stationary_covariance_covers_the_rt3003(name, method):
    """Issue 15: the level 3-sigma (datasheet + the measured disturbance: a parked car's 0.005-0.008 deg rms rocking
    here) covers the difference to the RT3003's roll/pitch at the last stationary sample (its own spec: 0.03 deg
    1-sigma, not added) and stays below 0.05 deg (not inflated); at 10 Hz outputs the heading is withheld (0016,
    19 s) or given with an azimuth 1-sigma near the 30 deg limit that covers the RT3003 yaw (0057, 28 s).
    Measured: docs/static_alignment.md, "Honest coarse covariance"."""
    t, rows = _load(DATA / f"{name}_oxts")
    n = STATIC_ROWS[name] or len(t)
    e = _run(t[:n], rows[:n], CoarseConfig.from_dict({**RT3003, "method": method}))
    err = earth.heading_error_enu_rad(e.C_b_n, earth.C_b_n_from_rpy(*rows[n - 1, 3:6]))
    s3 = 3 * np.sqrt(np.diag(e.P_att_n))
    assert np.all(np.abs(err[:2]) <= s3[:2]) and np.all(s3[:2] < math.radians(0.05)), (np.degrees(err), np.degrees(s3))
    if e.status is AlignmentStatus.ALIGNED:
        assert abs(err[2]) <= s3[2] and s3[2] > math.radians(45.0), (np.degrees(err), np.degrees(s3))
    else:
        assert e.status is AlignmentStatus.WAITING_FOR_DATA and NO_HEADING in e.reason, e.reason
