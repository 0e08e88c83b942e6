"""insalign-import INPUT OUT [--imu rates|increments] [--axes FLU|RFU|FRD|...] [--euler enu|ned] [--position LAT LON H]

Convert an IMU log (CSV or .npz: time, gyro and accelerometer as rates or increments, optional GNSS fixes and
reference attitude; columns in insalign_ros/io/importer.py and docs/bag_contract.md) to a contract rosbag2.
Axes and Euler conventions are converted once, at this boundary, to body FLU and ENU. Prints a report (rows
valid/rejected by reason, fixes, reference rows). Exit codes: 0 ok, 2 a user error (one line on stderr, no
traceback).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

PROG = "insalign-import"


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message):  # argparse prints usage + error; we promise one line and exit 2
        self.exit(2, f"{PROG}: {message} (see {PROG} --help)\n")


def main(argv=None) -> int:
    from ..io.bag import STORAGES, write_bag
    from ..io.importer import EULER_CONVENTIONS, IMU_COLUMNS, ImportDataError, import_table

    ap = _OneLineParser(prog=PROG, description=__doc__.splitlines()[2])
    ap.add_argument("input", type=Path, help="CSV (header row of column names) or .npz")
    ap.add_argument("out", type=Path, help="output bag directory (must not exist)")
    ap.add_argument("--imu", choices=tuple(IMU_COLUMNS), default="rates",
                    help="rates: wx_rad_s.. fx_m_s2..; increments: dthx_rad.. dvx_m_s.. over (t_k-1, t_k]")
    ap.add_argument("--axes", default="FLU", help="the IMU's x y z axes as F/B L/R U/D letters (FLU, RFU, FRD, ...)")
    ap.add_argument("--euler", choices=EULER_CONVENTIONS, default="enu",
                    help="reference attitude: enu = body FLU to ENU, yaw from East CCW (ROS); ned = body FRD to NED, "
                         "heading from North clockwise")
    ap.add_argument("--position", type=float, nargs=3, metavar=("LAT_DEG", "LON_DEG", "H_M"),
                    help="position of a vehicle that does not move (for the reference's truth pose without GNSS)")
    ap.add_argument("--storage", choices=STORAGES, default="sqlite3")
    try:
        a = ap.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (2, its line already printed)
        return int(exc.code or 0)
    if a.out.exists():
        print(f"{PROG}: {a.out} exists; refusing to overwrite", file=sys.stderr)
        return 2
    try:
        data, rep = import_table(a.input, imu=a.imu, axes=a.axes, euler=a.euler, position_llh=a.position)
    except (ImportDataError, OSError) as exc:
        print(f"{PROG}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    print(format_report(rep))
    write_bag(data, a.out, storage=a.storage)
    print(f"wrote {a.out}: {data.n} IMU samples, {data.gnss_t_s.shape[0]} fixes, truth "
          f"{'yes' if data.has_truth else 'no'}, {a.storage}")
    return 0


def format_report(rep: dict) -> str:
    from ..io.validation import format_counts

    s = (f"{rep['file']}: {rep['valid']} valid of {rep['rows']} rows ({rep['imu']}, axes {rep['axes']} -> FLU), "
         f"{rep['gnss_fixes']} GNSS fixes, {rep['reference_rows']} reference attitude rows ({rep['euler']})")
    if rep["rejected"]:
        s += "\n  rejected rows: " + format_counts(rep["rejected"])
    if rep.get("gnss_rejected"):
        s += "\n  rejected fixes: " + format_counts(rep["gnss_rejected"])
    return s


if __name__ == "__main__":
    sys.exit(main())
