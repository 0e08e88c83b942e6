"""Offline use of the session: ``align(source, core=...)`` on a bag, a scenario name or a ScenarioData.

The same :class:`AlignmentSession` the node runs: inputs are pushed in arrival order (a simulation's events in
stamp order; fixes delayed by ``fix_delay_s`` when asked, to reproduce receiver latency) and processed with
the same fusion delay, then drained at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core import earth
from ..core.types import GnssFix, GnssHeading, GnssVelocity, ImuSample, WheelSpeed
from .flag import AlignedCriteria
from ..core.recording import ScenarioData
from .config import SessionConfig
from .outputs import Output
from .session import AlignmentSession
from .truth import TruthSample, TruthTable  # noqa: F401  (TruthSample re-exported)
from .truth import truth_table_valid


@dataclass
class AlignResult:
    """Arrays of one offline alignment run (one row per output), plus metrics when truth exists.

    ``t_s`` [s data time]; ``rpy_deg`` roll, pitch, yaw estimate [deg] (yaw from East, CCW); ``sigma3_deg``
    their 3-sigma [deg] as the covariance gives it, for analysis: above ``core.stats.SIGMA3_UNKNOWN_DEG`` (180) the
    angle is unknown (``insalign-align`` writes "unknown", the node publishes NaN); ``aligned`` the session's flag; ``rpy_err_deg`` estimate minus truth (NaN without
    truth); ``nees`` attitude NEES (NaN without truth)."""

    core: str
    t_s: np.ndarray
    rpy_deg: np.ndarray
    sigma3_deg: np.ndarray
    aligned: np.ndarray
    rpy_err_deg: np.ndarray
    nees: np.ndarray
    status: list
    outputs: list = field(repr=False, default_factory=list)
    counters: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    init_t_s: float = float("nan")

    @property
    def estimates(self):
        return [o.estimate for o in self.outputs]


def load_source(source, duration_s: float | None = None, seed: int = 0, **reader_kwargs) -> ScenarioData:
    """A ScenarioData from a ScenarioData (returned as is), a bag path, or a scenario name (simulated)."""
    if isinstance(source, ScenarioData):
        data = source
    elif isinstance(source, (str, Path)) and Path(source).exists():
        from ..io.bag import read_bag

        data = read_bag(source, **reader_kwargs)
    elif isinstance(source, str):
        from ..sim.scenarios import SCENARIOS, make_scenario

        if source not in SCENARIOS and ("/" in source or "." in Path(source).name):
            raise FileNotFoundError(f"not found: {source}")  # a path, not a scenario name
        return make_scenario(source, seed=seed, duration_s=duration_s)
    elif isinstance(source, Path):
        raise FileNotFoundError(f"not found: {source}")
    else:
        raise ValueError(f"source: not a ScenarioData, an existing bag path or a scenario name: {source!r}")
    return truncate(data, duration_s) if duration_s is not None else data


def truncate(data: ScenarioData, duration_s: float) -> ScenarioData:
    """The first ``duration_s`` seconds of ``data`` (IMU, fixes, truth and validity)."""
    if not duration_s > 0:
        raise ValueError(f"duration: must be > 0, got {duration_s}")
    return data.until(float(data.t_s[0]) + duration_s)


def truth_table(data: ScenarioData) -> TruthTable | None:
    """The truth of ``data`` as a :class:`TruthTable` (None without truth): attitude, geodetic position, ENU velocity
    (or, without it, the ENU position relative to the first sample, differentiated by the session)."""
    if not data.has_truth:
        return None
    return TruthTable(data.t_s, data.C_b_n, np.stack([data.lat_rad, data.lon_rad, data.h_m], axis=1), data.v_n)


def truth_samples(data: ScenarioData):
    """TruthSample per IMU stamp of ``data`` (empty without truth): attitude, geodetic position, ENU velocity."""
    table = truth_table(data)
    return [] if table is None else [table.sample(k) for k in range(data.n)]


def vehicle_inputs(data: ScenarioData) -> tuple[np.ndarray, list]:
    """The source's wheel speeds and dual-antenna headings in stamp order: (stamps (n,) [s], [(kind, item)])."""
    ev = []
    if data.wheel_t_s is not None:
        ev += [(float(t), "wheel", WheelSpeed(float(t), float(s), float(v)))
               for t, s, v in zip(data.wheel_t_s, data.wheel_speed_m_s, data.wheel_var_m2_s2)]
    if data.heading_t_s is not None:
        ev += [(float(t), "heading", GnssHeading(float(t), float(y), float(v)))
               for t, y, v in zip(data.heading_t_s, data.heading_yaw_rad, data.heading_var_rad2)]
    ev.sort(key=lambda e: e[0])
    return np.array([e[0] for e in ev], float), [(e[1], e[2]) for e in ev]


def _push_vehicle_input(session: AlignmentSession, kind: str, item) -> None:
    (session.push_wheel_speed if kind == "wheel" else session.push_gnss_heading)(item)


def events_in_arrival_order(data: ScenarioData, fix_delay_s: float = 0.0):
    """(kind, item) in the order a live system would receive them: IMU in stamp order, a fix (and a GNSS velocity,
    kind "vel", where the source has them) once the IMU has reached ``stamp + fix_delay_s``, truth with its IMU
    sample, wheel speeds and headings (kinds "wheel", "heading") like the velocities. Samples and fixes the source
    flags invalid are left out (the session sees a gap)."""
    truth = truth_samples(data)
    j = jv = ja = 0
    a_t, aux = vehicle_inputs(data)
    v_t = data.gnss_vel_t_s if data.gnss_vel_t_s is not None else np.zeros(0)
    g_t = data.gnss_t_s
    imu_ok, gnss_ok = data.imu_valid_mask, data.gnss_valid_mask
    for k in range(data.n):
        t = float(data.t_s[k])
        if truth:
            yield "truth", truth[k]
        if imu_ok[k]:  # a sample the source flags invalid (e.g. a KITTI fill row) is not data: a gap
            yield "imu", ImuSample(t, data.omega_ib_b[k], data.f_ib_b[k])
        while j < g_t.shape[0] and g_t[j] + fix_delay_s <= t:
            if gnss_ok[j]:
                yield "fix", GnssFix(float(g_t[j]), data.gnss_p_e[j], data.gnss_R_e[j])
            j += 1
        while jv < v_t.shape[0] and v_t[jv] + fix_delay_s <= t:
            yield "vel", GnssVelocity(float(v_t[jv]), data.gnss_vel_n[jv], data.gnss_vel_R_n[jv])
            jv += 1
        while ja < a_t.shape[0] and a_t[ja] + fix_delay_s <= t:
            yield aux[ja]
            ja += 1
    yield from aux[ja:]
    for jv in range(jv, v_t.shape[0]):
        yield "vel", GnssVelocity(float(v_t[jv]), data.gnss_vel_n[jv], data.gnss_vel_R_n[jv])
    for j in range(j, g_t.shape[0]):  # delayed fixes still on their way when the IMU stream ended
        if gnss_ok[j]:
            yield "fix", GnssFix(float(g_t[j]), data.gnss_p_e[j], data.gnss_R_e[j])


def run_session(session: AlignmentSession, data: ScenarioData, fix_delay_s: float = 0.0, chunk: int = 1000,
                progress=None) -> list[Output]:
    """Push ``data`` into ``session`` in arrival order, processing every ``chunk`` IMU samples; drain at the end.

    With the session's fast path on, the IMU goes in as arrays between the points where something else arrives
    (a fix) or the loop processes (every ``chunk`` samples): the same arrival order and processing points as one
    push per sample, so the same numbers (test/test_speed_paths.py)."""
    if session.fast_path and data.n > 0 and bool(np.all(np.diff(data.t_s) > 0)):
        session._deferred_errors = []  # the outputs' Euler errors in one call at the end
        try:
            return _run_session_arrays(session, data, fix_delay_s, chunk, progress)
        finally:
            session.outputs.fill_deferred_errors()
    out: list[Output] = []
    n_imu = 0
    for kind, item in events_in_arrival_order(data, fix_delay_s):
        if kind == "imu":
            session.push_imu(item)
            n_imu += 1
            if n_imu % chunk == 0:
                out += session.process()
                if progress is not None:
                    progress.update(chunk)
        elif kind == "fix":
            session.push_fix(item)
        elif kind == "vel":
            session.push_velocity(item)
        elif kind in ("wheel", "heading"):
            _push_vehicle_input(session, kind, item)
        else:
            session.push_truth(item)
    out += session.finish()
    if progress is not None:
        progress.update(n_imu % chunk)
    return out


def _run_session_arrays(session: AlignmentSession, data: ScenarioData, fix_delay_s: float, chunk: int,
                        progress) -> list[Output]:
    """``run_session`` with array pushes (``push_imu_arrays``); events in the order of ``events_in_arrival_order``."""
    out: list[Output] = []
    truth = truth_table(data)
    t = data.t_s
    imu_ok, gnss_ok = data.imu_valid_mask, data.gnss_valid_mask
    n_valid = np.cumsum(imu_ok)  # valid IMU samples pushed up to and including index k
    # a fix arrives after the IMU sample at which its stamp + delay is reached (in order: a late one holds the next)
    g = np.asarray(data.gnss_t_s, float)
    arrive = np.maximum.accumulate(np.searchsorted(t, g + fix_delay_s, side="left")) if g.size else np.zeros(0, int)
    stops = set(arrive[arrive < data.n].tolist())
    gv = np.asarray(data.gnss_vel_t_s if data.gnss_vel_t_s is not None else np.zeros(0), float)
    arrive_v = np.maximum.accumulate(np.searchsorted(t, gv + fix_delay_s, side="left")) if gv.size \
        else np.zeros(0, int)
    stops.update(arrive_v[arrive_v < data.n].tolist())
    jv = ja = 0
    a_t, aux = vehicle_inputs(data)
    arrive_a = np.maximum.accumulate(np.searchsorted(t, a_t + fix_delay_s, side="left")) if a_t.size \
        else np.zeros(0, int)
    stops.update(arrive_a[arrive_a < data.n].tolist())
    stops.update(np.flatnonzero(imu_ok & (n_valid % chunk == 0)).tolist())
    stops.add(data.n - 1)
    # the valid rows, checked once (the checks are row-wise: a push's are the slice of these)
    vi = np.flatnonzero(imu_ok)
    tv = np.ascontiguousarray(t[vi], float)
    wv = np.ascontiguousarray(data.omega_ib_b[vi], float)
    fv = np.ascontiguousarray(data.f_ib_b[vi], float)
    ok, cont = session.inputs.imu_array_checks(tv, wv, fv)
    truth_ok = truth is not None and truth_table_valid(truth)
    if truth_ok:
        session.outputs.defer_truth(truth)  # the outputs' truth from the table at the end
    j = 0
    a = 0
    for b in sorted(stops):
        if truth is not None:
            session.push_truth_table(truth, a, b + 1, checked=truth_ok)
        p, q = int(n_valid[a] - imu_ok[a]), int(n_valid[b])  # the valid rows a..b
        if q > p:
            session.inputs.push_imu_checked(tv[p:q], wv[p:q], fv[p:q], ok[p:q], cont[p:q - 1])
        if imu_ok[b] and n_valid[b] % chunk == 0:
            out += session.process()
            if progress is not None:
                progress.update(chunk)
        while j < g.shape[0] and arrive[j] == b:
            if gnss_ok[j]:
                session.push_fix(GnssFix(float(g[j]), data.gnss_p_e[j], data.gnss_R_e[j]))
            j += 1
        while jv < gv.shape[0] and arrive_v[jv] == b:
            session.push_velocity(GnssVelocity(float(gv[jv]), data.gnss_vel_n[jv], data.gnss_vel_R_n[jv]))
            jv += 1
        while ja < a_t.shape[0] and arrive_a[ja] == b:
            _push_vehicle_input(session, *aux[ja])
            ja += 1
        a = b + 1
    for jv in range(jv, gv.shape[0]):
        session.push_velocity(GnssVelocity(float(gv[jv]), data.gnss_vel_n[jv], data.gnss_vel_R_n[jv]))
    for kind, item in aux[ja:]:
        _push_vehicle_input(session, kind, item)
    for j in range(j, g.shape[0]):  # delayed fixes still on their way when the IMU stream ended
        if gnss_ok[j]:
            session.push_fix(GnssFix(float(g[j]), data.gnss_p_e[j], data.gnss_R_e[j]))
    out += session.finish()
    if progress is not None:
        progress.update(int(n_valid[-1]) % chunk)
    return out


def align(source, core: str | None = None, duration_s: float | None = None, seed: int = 0,
          core_params: dict | None = None, criteria: dict | None = None, fix_delay_s: float = 0.0,
          progress=None, reader_kwargs: dict | None = None, **session_params) -> AlignResult:
    """Align ``source`` (a bag path, a scenario name or a ScenarioData) with one core; return arrays and metrics.

    ``session_params``: fields of :class:`SessionConfig` (e.g. ``init_mode="truth"``, ``init_rpy_error_deg``,
    ``initial_rpy_deg``, ``output_period_s``); ``core_params``: the core's config fields; ``criteria``: the
    aligned-flag criteria (session/flag.py); ``core`` None: SessionConfig's default (``auto``). A source without truth cannot use ``init_mode="truth"``."""
    data = load_source(source, duration_s, seed, **(reader_kwargs or {}))
    cfg = SessionConfig.from_dict({**({} if core is None else {"core": core}), **session_params})
    if cfg.init_mode == "truth" and not data.has_truth:
        raise ValueError("init_mode 'truth': the data have no truth; give initial_rpy_deg (init_mode 'guess')")
    session = AlignmentSession(cfg, core_params, AlignedCriteria(**(criteria or {})))
    try:
        outs = run_session(session, data, fix_delay_s, progress=progress)
        return result_from_outputs(cfg.core, outs, session, data)
    finally:
        session.close()


def result_from_outputs(core: str, outs: list[Output], session: AlignmentSession, data: ScenarioData) -> AlignResult:
    from ..eval import metrics as MT

    n = len(outs)
    t = np.array([o.stamp_s for o in outs])
    rpy = np.degrees(earth.rpy_from_C_b_n(np.array([o.estimate.C_b_n for o in outs]).reshape(n, 3, 3)))
    s3 = np.array([o.euler_3sigma_deg for o in outs]).reshape(n, 3)
    err = np.full((n, 3), np.nan)
    nees = np.full(n, np.nan)
    metrics: dict = {}
    init_t = session.init_t if session.init_t is not None else float("nan")
    if data.has_truth and n:
        r = MT.evaluate(core, [o.estimate for o in outs], data.t_s, data.C_b_n, init_t)
        err, nees = r.rpy_err_deg, r.nees
        metrics = MT.summary(r)
    aligned = np.array([o.aligned for o in outs], bool)
    c = session.counters
    # from the outputs, not the session's current flag and initialisation (a restart resets those): the first flag of
    # the whole run, the span from the first IMU sample, and the restarts with the reasons in the status column
    metrics.update(core=core, duration_s=float(t[-1] - data.t_s[0]) if n and data.n else 0.0,
                   aligned_first_raised_at_s=float(t[np.argmax(aligned)]) if aligned.any() else None,
                   restarts=int(c.get("divergences", 0) + c.get("core_faults", 0) + c.get("time_resets", 0)),
                   final_aligned=bool(aligned[-1]) if n else False, events=events_of(session))
    return AlignResult(core, t, rpy, s3, aligned, err, nees, [o.status.value for o in outs], outs,
                       dict(session.counters), session.diagnostics(), metrics, init_t)


def events_of(session: AlignmentSession) -> list[dict]:
    """What happened, in order: every restart (FAULT and re-initialisation, with its reason), every flag rise and
    drop (with the reason): ``{"t_s", "event": "restart" | "flag_raised" | "flag_lowered", "reason"}`` [s data
    time]. The metrics JSON carries it; the CSV's ``event`` column puts each on its output row."""
    out = []
    for t, up, reason in session.flag_changes:
        kind = "flag_raised" if up else "restart" if str(reason).startswith("fault (") else "flag_lowered"
        out.append({"t_s": float(t), "event": kind, "reason": str(reason)})
    return out


def event_column(t_s: np.ndarray, events: list[dict]) -> list[str]:
    """Per output row the events since the row before (``kind: reason``, joined by " | "; "" for none)."""
    col = [""] * len(t_s)
    for e in events:
        i = min(int(np.searchsorted(t_s, e["t_s"], side="left")), len(t_s) - 1) if len(t_s) else -1
        if i >= 0:
            col[i] = (col[i] + " | " if col[i] else "") + f"{e['event']}: {e['reason']}"
    return col


def flag_up_with_error_above(result: AlignResult, bound_deg: float) -> int:
    """Outputs with the flag up while |yaw error| > bound (0 without truth): the aligned flag's safety count."""
    if not np.any(np.isfinite(result.rpy_err_deg)):
        return 0
    return int(np.sum(result.aligned & (np.abs(result.rpy_err_deg[:, 2]) > bound_deg)))

