"""AlignmentSession: the whole alignment pipeline behind the node, ``insalign-align``, the API and the benchmarks.

Push inputs in arrival order (``push_imu``, ``push_imu_arrays``, ``push_fix``, ``push_velocity``, ``push_truth``),
call ``process()`` (a node timer, or the offline loop), read the returned :class:`Output` records and
``diagnostics()``. No ROS import.

The session is a short orchestrator over stages, each a module with one job (docs/architecture.md):

* ``inputs`` (:class:`InputStage`): validation at the door (counted per reason, never raised), duplicate and
  time-jump checks, the time-ordered buffer (``buffers``);
* ``loop`` (:class:`Loop`): the filter runs ``max_fix_lag_s`` behind the newest IMU sample (a fixed fusion delay),
  so a fix that arrives up to that late is fused at its own stamp; runs without events go to the core as arrays;
  spikes are dropped and gaps bridged (``gaps``) with the covariance inflated by what the bridge may get wrong;
* ``initialiser`` (:class:`Initialiser`): truth / guess / sensors (yaw bank);
* ``fusion`` (:class:`Fusion`): the schedule of fixes, GNSS velocities, zero-velocity updates, backtracking;
* ``guard`` (:class:`DivergenceGuard`): outlier gate, GNSS jumps, NIS window, CUSUM, covariance sanity;
* ``monitor`` (:class:`Monitor`) and ``flag`` (:class:`AlignedFlag`): the flag, the watchdog, status and
  diagnostics;
* ``outputs`` (:class:`Outputs`): one record per ``output_period_s`` of data time.

The session owns what they share (configuration, counters, the core, the buffer, the time line, the flag) and the
life cycle: reset (everything), restart after a fault or a divergence (keep the time line and the buffered inputs,
re-initialise from the data that follow).
"""

from __future__ import annotations

import math
import time
import traceback
from collections import OrderedDict

from ..filters.base import AlignmentCore, AlignmentStatus
from ..filters.imu_grade import get_grade
from .catalog import check_core_config, resolve_core_params
from .buffers import Pending, Ring  # noqa: F401  (Ring re-exported: the node's diagnostics windows)
from .config import SessionConfig
from .flag import AlignedCriteria, AlignedFlag, level_floor_3sigma_deg
from .fusion import Fusion
from .grade_check import GradeCheck
from .guard import DivergenceGuard
from .initialiser import Initialiser
from .inputs import InputStage
from .loop import Loop
from .monitor import Monitor
from .outputs import Output, Outputs
from .yaw_seed import YawSeed
from .truth import TruthSample, TruthTable, truth_table_valid  # noqa: F401  (re-exported)

COUNTERS = (
    "imu_received", "imu_processed", "imu_rejected", "imu_invalid", "imu_frame", "imu_duplicate", "imu_out_of_order",
    "imu_reordered", "imu_future", "imu_gaps", "imu_before_init", "gnss_received", "gnss_accepted", "gnss_rejected",
    "gnss_invalid", "gnss_no_fix", "gnss_frame", "gnss_duplicate", "gnss_stale", "gnss_future", "gnss_before_init",
    "gnss_filter_rejected", "gnss_unused", "truth_received", "truth_invalid", "time_resets", "core_faults",
    "zupt_accepted", "watchdog_trips", "inputs_dropped", "gnss_gated", "imu_spikes", "divergences")
COUNTERS += ("gnss_jumps", "gnss_holds", "divergences_nis", "divergences_covariance", "divergences_cusum",
             "divergence_widened")  # guard
COUNTERS += ("grade_too_optimistic", "gnss_heading_disagrees")  # grade_check.py: the data contradict the declared imu_grade
COUNTERS += ("reinit_restarts",)  # divergence guard: a re-initialisation restarted after a GNSS jump
COUNTERS += ("gnss_implausible",)  # a fix off the vehicle's own recent fixes while no filter claims its attitude
#: GNSS velocity (push_velocity): received, fused, rejected (total) and per reason
VEL_COUNTERS = ("gnss_vel_received", "gnss_vel_accepted", "gnss_vel_rejected", "gnss_vel_invalid",
                "gnss_vel_duplicate", "gnss_vel_stale", "gnss_vel_future", "gnss_vel_before_init", "gnss_vel_gated",
                "gnss_vel_filter_rejected", "gnss_vel_unused")
COUNTERS = COUNTERS + VEL_COUNTERS
#: wheel speed (push_wheel_speed) and dual-antenna GNSS heading (push_gnss_heading): received, rejected (total) and
#: per reason, fused, and unused (taken out of the buffer at their stamps but not fused: session/fusion.py)
AUX_COUNTERS = tuple(f"{topic}_{what}" for topic in ("wheel_speed", "gnss_heading")
                     for what in ("received", "rejected", "invalid", "duplicate", "stale", "future", "fused", "unused"))
COUNTERS = COUNTERS + AUX_COUNTERS + ("gnss_heading_filter_rejected",)
#: wheel speed: rejected by the WheelSpeed model's NIS gate; scale-factor windows fused and rejected (wheel_scale.py)
COUNTERS += ("wheel_speed_filter_rejected", "wheel_scale_windows", "wheel_scale_rejected")
#: the non-holonomic constraint of ``vehicle`` car / wheeled_robot (session/fusion.py): fused, gated, switched off
COUNTERS += ("nhc_accepted", "nhc_rejected", "nhc_switched_off", "nhc_misfit")


class AlignmentSession:
    """The alignment pipeline. ``core_params``: the core's config fields; ``criteria``: the aligned-flag criteria."""

    #: the most IMU samples held for reordering / the fusion delay; beyond it the oldest are processed at once
    MAX_BUFFER = 200_000
    #: process runs of IMU samples between events as arrays (the loop's fast run); False: one step per sample
    fast_path: bool = True
    #: (core, its estimate) while the core's state has not changed since (``Outputs.estimate``)
    _est_memo: tuple | None = None
    #: outputs whose Euler error is filled in later by ``Outputs.fill_deferred_errors`` (offline); None: at once
    _deferred_errors: list | None = None

    def __init__(self, config: SessionConfig | dict | None = None, core_params: dict | None = None,
                 criteria: AlignedCriteria | None = None, log=None) -> None:
        self.cfg = config if isinstance(config, SessionConfig) else SessionConfig.from_dict(config)
        self.cfg.validate()
        # the IMU grade's noise and bias fields under the explicit core parameters (filters/imu_grade.py)
        self.core_params = resolve_core_params(self.cfg, core_params)
        check_core_config(self.cfg, self.core_params)  # validate now (ValueError with the reason)
        self.flag = AlignedFlag(criteria or AlignedCriteria(), level_floor_3sigma_deg(self.core_params.get(
            "acc_bias_mg", get_grade(self.cfg.imu_grade).acc_bias_mg)))
        self.log = log or (lambda level, key, text: None)
        self.counters: OrderedDict[str, int] = OrderedDict((k, 0) for k in COUNTERS)
        self.core: AlignmentCore | None = None
        self.bt = None  # filters/backtrack.BacktrackingAligner when backtrack_passes > 0
        self.last_reject = ""
        self.timing = {"process_s": 0.0, "process_calls": 0, "samples": 0}
        #: added to stamps in log lines and diagnostics (the node's epoch: users see their header stamps)
        self.stamp_offset_s = 0.0
        #: outputs of processing forced by a full buffer inside push_imu*, handed out by the next process()/finish()
        self._overflow_out: list[Output] = []
        self.inputs = InputStage(self)
        self.loop = Loop(self)
        self.initialiser = Initialiser(self)
        self.fusion = Fusion(self)
        self.guard = DivergenceGuard(self)
        self.monitor = Monitor(self)
        self.grade_check = GradeCheck(self)
        self.outputs = Outputs(self)
        self.yaw_seed = YawSeed(self)
        self._reset_state("start")

    # ------------------------------------------------------------------ inputs (the input stage)
    def push_imu(self, sample, wall_s: float | None = None) -> bool:
        """Validate and buffer one IMU sample (omega_ib_b [rad/s], f_ib_b [m/s^2], body FLU). False if rejected."""
        return self.inputs.push_imu(sample, wall_s)

    def push_imu_arrays(self, t_s, omega_ib_b, f_ib_b, wall_s: float | None = None) -> int:
        """``push_imu`` for arrays of samples (t_s (N,) [s], omega_ib_b (N, 3) [rad/s], f_ib_b (N, 3) [m/s^2], in
        arrival order); returns how many were accepted (InputStage.push_imu_arrays)."""
        return self.inputs.push_imu_arrays(t_s, omega_ib_b, f_ib_b, wall_s)

    def push_fix(self, fix, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS position fix (ECEF p_e [m], R_e [m^2]). False if rejected."""
        return self.inputs.push_fix(fix, wall_s)

    def push_velocity(self, vel, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS velocity (ENU antenna velocity v_n [m/s], R_n [m^2/s^2]). False if rejected."""
        return self.inputs.push_velocity(vel, wall_s)

    def push_wheel_speed(self, ws, wall_s: float | None = None) -> bool:
        """Validate and buffer one wheel speed (core.types.WheelSpeed: along the vehicle's x axis [m/s], variance
        [m^2/s^2]); taken at its stamp by the fusion (session/fusion.py). False if rejected."""
        return self.inputs.push_wheel_speed(ws, wall_s)

    def push_gnss_heading(self, heading, wall_s: float | None = None) -> bool:
        """Validate and buffer one dual-antenna GNSS heading (core.types.GnssHeading: baseline yaw ENU [rad],
        variance [rad^2]); taken at its stamp by the fusion (session/fusion.py). False if rejected."""
        return self.inputs.push_gnss_heading(heading, wall_s)

    def push_truth(self, truth: TruthSample) -> None:
        """A reference pose (initialisation in init_mode 'truth', and the Euler errors of the outputs)."""
        self.inputs.push_truth(truth)

    def push_truth_table(self, table: TruthTable, start: int = 0, stop: int | None = None,
                         checked: bool = False) -> None:
        """``push_truth`` for rows ``start:stop`` of a :class:`TruthTable` (the offline path)."""
        self.inputs.push_truth_table(table, start, stop, checked)

    def reject_input(self, topic: str, counter: str, reason: str, wall_s: float | None = None) -> None:
        """Count an input the caller rejected before it became a sample (a message's frame, covariance, status)."""
        self.inputs.reject_input(topic, counter, reason, wall_s)

    # ------------------------------------------------------------------ configuration and life cycle
    def reconfigure(self, config: SessionConfig, core_params: dict, criteria: AlignedCriteria) -> bool:
        """Apply new parameters. Returns True when the alignment was restarted (core or core parameters changed)."""
        config.validate()
        core_params = resolve_core_params(config, core_params)
        check_core_config(config, core_params)
        restart = (config.core != self.cfg.core or core_params != self.core_params
                   or config.init_mode != self.cfg.init_mode or config.backtrack_passes != self.cfg.backtrack_passes)
        self.cfg, self.core_params = config, dict(core_params)
        self.flag.set_criteria(criteria)
        if restart:
            self.reset("parameters changed")
        return restart

    def reset(self, why: str) -> None:
        """Drop the core and every buffered input; start over (the flag goes down)."""
        self._reset_state(why)

    def close(self) -> None:
        self._close_core()

    def _close_core(self) -> None:
        if self.core is not None:
            self.core.close()
        if self.bt is not None and self.bt.live is not self.core:
            self.bt.live.close()
        self.core, self.bt = None, None

    def _reset_state(self, why: str) -> None:
        self._close_core()
        self.buf = Pending()
        self.status = AlignmentStatus.WAITING_FOR_DATA
        self.reason = f"waiting for IMU data ({why})"
        self.fault_reason = ""
        self.newest_imu_t: float | None = None
        self.processed_t: float | None = None  # stamp of the last processed IMU sample (= the core's time)
        for stage in (self.inputs, self.loop, self.initialiser, self.fusion, self.guard, self.monitor, self.outputs,
                      self.yaw_seed, self.grade_check):
            stage.reset()
        self.initialiser.after_restart = why != "start"  # the vehicle may be moving: start from what the data say
        self.init_t: float | None = None
        self.anchor: tuple[float, float, float] | None = None
        self.next_out_t = -math.inf
        self.next_zupt_t = -math.inf
        self.next_nhc_t = -math.inf  # the next non-holonomic constraint (fusion.nhc_due)
        self.nhc_rejected_run = 0
        self.nhc_off_until_t = -math.inf
        self.nhc_misfit = ""  # the status note when the vehicle does not drive like the declared one (fusion.py)
        self.last_output: Output | None = None
        self.last_nis = float("nan")
        self.last_accepted_fix_t: float | None = None
        self.last_imu_wall: float | None = None
        self.last_input_wall: float | None = None
        self.watchdog_reason = ""
        self._used_fix_stamp: float | None = None
        self._used_vel_stamp: float | None = None  # the GNSS velocity that gave the initial velocity (not fused again)
        self.flag_changes: list[tuple[float, bool, str]] = []
        self.flag.reset()

    def process(self, wall_s: float | None = None, final: bool = False) -> list[Output]:
        """Process buffered inputs up to the fusion horizon (all of them when ``final`` or idle); return outputs.

        ``wall_s``: the caller's wall clock [s] (node: time.monotonic()); drives the watchdog and the idle drain."""
        t0 = time.perf_counter()
        if wall_s is not None and not final and self.last_input_wall is not None \
                and wall_s - self.last_input_wall >= self.cfg.idle_drain_s:
            final = True
        until = math.inf if final else (self.newest_imu_t - self.cfg.max_fix_lag_s
                                        if self.newest_imu_t is not None else -math.inf)
        out = self._take_overflow() + self.loop.run(until)
        self.fusion.background(math.inf if final and self.cfg.backtrack_budget_s == math.inf else self.cfg.backtrack_budget_s)
        if wall_s is not None:
            self.monitor.watchdog(wall_s)
        self.timing["process_s"] += time.perf_counter() - t0
        self.timing["process_calls"] += 1
        return out

    def finish(self) -> list[Output]:
        """Process everything buffered (end of a recording); run pending backtracking passes to the end."""
        out = self._take_overflow() + self.loop.run(math.inf)
        if self.bt is not None:
            self.bt.run_until_done()
            self.fusion.after_handover()
        return out

    def _take_overflow(self) -> list[Output]:
        out, self._overflow_out = self._overflow_out, []
        return out

    def _diverged(self, reason: str) -> None:
        """Divergence: FAULT with the reason, the flag down at once, re-initialisation from the data that follow."""
        self.counters["divergences"] += 1
        self.log("error", "divergence", f"divergence: {reason}; re-initialising from the sensors (yaw bank)")
        self._reinitialise(f"divergence: {reason}")

    def _reinitialise(self, why: str) -> None:
        """FAULT with ``why`` and a re-initialisation from the sensors, keeping the fix sequence (jump detection)
        and the level the lost filter claims (if it does)."""
        seq, vref = self.guard.fix_seq, self.guard.vel_ref
        kept = self.initialiser.claimed_level()
        self._restart(why)
        self.guard.fix_seq, self.guard.vel_ref = seq, vref  # jump detection continues across the re-initialisation
        self.initialiser.kept_level = kept
        self.initialiser.sensors_reinit = True  # whatever the first initialisation was: a guess or the truth no longer holds

    def _fault(self, exc: Exception) -> None:
        self.counters["core_faults"] += 1
        self.last_reject = f"fault: {type(exc).__name__}: {exc}"
        self.log("error", "fault", f"core fault ({type(exc).__name__}: {exc}); resetting the alignment\n"
                                   f"{traceback.format_exc(limit=3)}")
        self._restart(f"{type(exc).__name__}: {exc}")

    def _restart(self, why: str) -> None:
        """Drop the core, keep the time line and the buffered inputs, status FAULT: re-initialise from what follows."""
        keep_t = self.processed_t
        resets = dict(self.counters)
        newest, recent, screen = self.newest_imu_t, self.inputs.recent_stamps, self.inputs.screen
        pending = self.buf
        last_reject, offset, changes = self.last_reject, self.stamp_offset_s, self.flag_changes
        self._reset_state(f"after {why}")
        self.flag_changes = changes  # the event list (offline CSV/JSON) survives the restart
        self.counters.update(resets)
        self.last_reject, self.stamp_offset_s = last_reject, offset
        # keep the time line and the buffered inputs: re-initialise from the data that follow
        self.buf, self.newest_imu_t, self.inputs.recent_stamps, self.inputs.screen = pending, newest, recent, screen
        self.processed_t = keep_t
        self.status = AlignmentStatus.FAULT
        self.fault_reason = why
        self.reason = f"fault ({why}); re-initialising"
        self.flag_changes.append((keep_t or 0.0, False, self.reason))

    @property
    def aligned(self) -> bool:
        return self.flag.aligned and not self.watchdog_reason

    @property
    def filter_time_s(self) -> float | None:
        return self.processed_t

    # ------------------------------------------------------------------ status (the monitor stage)
    def level(self) -> int:
        """Diagnostic level: 0 OK (aligned, fresh inputs), 1 WARN, 2 ERROR (fault)."""
        return self.monitor.level()

    def message(self) -> str:
        return self.monitor.message()

    def diagnostics(self) -> dict:
        """Key/value pairs for /diagnostics and the metrics JSON (strings, numbers, lists)."""
        return self.monitor.diagnostics()
