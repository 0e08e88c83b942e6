"""insalign-kitti2bag DRIVE_DIR OUT [--gnss-rate HZ] [--gnss-velocity] [--storage sqlite3|mcap] [--fill-rows mark|drop|keep]

Convert a KITTI raw OXTS drive (synced 10 Hz or extract 100 Hz layout) to a rosbag2 per docs/bag_contract.md.
Prints a report (valid/rejected sample counts by reason, gaps, rate, fill rows: the RT3003's interpolated rows with
mode -1, marked invalid in the bag by default). Exit codes: 0 ok, 2 the drive cannot be
converted or bad arguments (one-line reason on stderr, no traceback).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    from ..io.bag import STORAGES, write_bag
    from ..io.kitti import FILL_POLICIES, KittiError, convert_drive, format_report

    ap = argparse.ArgumentParser(prog="insalign-kitti2bag", description=__doc__.splitlines()[2])
    ap.add_argument("drive_dir", type=Path, help="drive directory (containing oxts/) or the oxts directory")
    ap.add_argument("out", type=Path, help="output bag directory (must not exist)")
    ap.add_argument("--gnss-rate", type=float, default=1.0,
                    help="GNSS fix rate [Hz] subsampled from the OXTS samples (<= 0: every sample; default 1)")
    ap.add_argument("--storage", choices=STORAGES, default="sqlite3")
    ap.add_argument("--fill-rows", choices=FILL_POLICIES, default="mark",
                    help="rows the RT3003 interpolated (mode -1): mark them invalid in the bag (default; "
                         "/imu/data_invalid, /gps/fix_invalid), drop them (gaps), or keep them as data")
    ap.add_argument("--gnss-velocity", action="store_true",
                    help="also a GNSS velocity at each fix (/gps/vel: the RT3003's ve/vn/vu, 1-sigma vel_accuracy)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    if a.out.exists():
        print(f"insalign-kitti2bag: {a.out} exists; refusing to overwrite", file=sys.stderr)
        return 2
    try:
        data, rep = convert_drive(a.drive_dir, gnss_rate_hz=a.gnss_rate, fill_policy=a.fill_rows, gnss_velocity=a.gnss_velocity,
                                  progress=not a.no_progress and sys.stderr.isatty())
    except (KittiError, OSError) as exc:
        print(f"insalign-kitti2bag: {exc}", file=sys.stderr)
        return 2
    print(format_report(rep))
    write_bag(data, a.out, storage=a.storage, progress=not a.no_progress and sys.stderr.isatty())
    print(f"wrote {a.out}: {data.n} IMU samples ({int((~data.imu_valid_mask).sum())} flagged invalid), "
          f"{data.gnss_t_s.shape[0]} fixes ({int((~data.gnss_valid_mask).sum())} flagged invalid), "
          + (f"{data.gnss_vel_t_s.shape[0]} velocities, " if data.has_gnss_velocity else "") + a.storage)
    return 0


if __name__ == "__main__":
    sys.exit(main())
