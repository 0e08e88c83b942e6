"""Runs of ``sensor_msgs/Imu`` and ``geometry_msgs/PoseStamped`` messages of a ROS 2 bag, decoded (io/cdr_fast.py)
and validated at once for io/bag.py: the same samples, rejections and reasons as taking them one by one
(test_bag_fast_cdr), at well under a microsecond a message instead of ~6. No ROS import."""

from __future__ import annotations

import numpy as np

from . import cdr_fast, validation


def _vectors_ok(v: np.ndarray, max_norm: float) -> np.ndarray:
    """Rows that ``validation.check_vector`` passes: finite, norm <= max_norm."""
    return np.isfinite(v).all(axis=1) & (np.sqrt((v * v).sum(axis=1)) <= max_norm)


def take_block(kind: str, items: list, prev_t_s: float | None, got: dict, rejected: dict, frames: dict,
               streams: dict) -> tuple[bool, float | None]:
    """Take ``items`` ((topic, raw CDR bytes) of one stream, ``kind`` "imu" or "truth", in bag order) as io/bag.py
    takes each: frame ids noted, the stamp (strictly after the last taken, ``prev_t_s`` [s]) and the fields checked,
    the valid ones appended to ``got[kind]``, the others counted per topic and reason. Returns (done, the stamp of
    the last one taken); (False, prev_t_s) with nothing done when the run is not one exact layout and length."""
    if not items:
        return True, prev_t_s
    topics = [t for t, _ in items]
    dec = (cdr_fast.imu_block if kind == "imu" else cdr_fast.pose_block)([r for _, r in items])
    if dec is None:
        return False, prev_t_s
    t_ns, frame_ids, a, b = dec
    for topic, frame in set(zip(topics, frame_ids)):
        frames[topic].add(frame)
    ts = t_ns * 1e-9
    with np.errstate(invalid="ignore", over="ignore"):
        if kind == "imu":
            fields_ok = _vectors_ok(a, validation.MAX_RATE_RAD_S) & _vectors_ok(b, validation.MAX_SPECIFIC_FORCE_M_S2)
        else:
            fields_ok = (np.abs(np.sqrt((b * b).sum(axis=1)) - 1.0) <= 1e-6) & np.isfinite(a).all(axis=1)
    # the last stamp taken before each message: a message is taken when its fields pass and its stamp is after
    # that; one with bad fields is not taken (no later stamp is compared with it) and one taken raises it
    last = np.maximum.accumulate(np.where(fields_ok, ts, -np.inf))
    before = np.maximum(-np.inf if prev_t_s is None else prev_t_s, np.concatenate([[-np.inf], last[:-1]]))
    taken = fields_ok & (ts > before)
    for k in np.flatnonzero(~taken):
        if ts[k] <= before[k]:
            reason = "duplicate stamp" if ts[k] == before[k] else "non-monotonic stamp"
        elif kind == "imu":
            reason = validation.check_imu(tuple(a[k].tolist()), tuple(b[k].tolist()))
        else:
            reason = validation.check_pose(tuple(a[k].tolist()), tuple(b[k].tolist()))
        rejected[topics[k]][reason] += 1
    idx = np.flatnonzero(taken)
    g = got[kind]
    g["t"].append(t_ns[idx])  # blocks among the one-by-one rows: stack() joins them in order
    if kind == "imu":
        g["w"].append(a[idx]), g["f"].append(b[idx])
        g["ok"].append(np.array([streams[topics[k]][1] for k in idx.tolist()], bool))
    else:
        g["p"].append(a[idx]), g["q"].append(b[idx])
    return True, (float(ts[idx[-1]]) if idx.size else prev_t_s)


def stack(got: dict) -> None:
    """The IMU and truth lists of io/bag.py's reader as arrays, in order: the blocks of :func:`take_block` (arrays)
    and the runs of rows taken one by one (tuples, ints, bools) between them."""
    for kind, keys in (("imu", ("t", "w", "f", "ok")), ("truth", ("t", "p", "q"))):
        for key in keys:
            parts, run = [], []
            for x in got[kind][key]:
                if isinstance(x, np.ndarray):
                    parts += [np.array(run, x.dtype).reshape((-1,) + x.shape[1:])] if run else []
                    parts.append(x)
                    run = []
                else:
                    run.append(x)
            if run or not parts:
                parts.append(np.array(run, bool if key == "ok" else np.int64 if key == "t" else float))
            got[kind][key] = np.concatenate(parts) if len(parts) > 1 else parts[0]
