"""Over DDS (issue 24, item 5): a driver that stamps on the host, 5 ms of stamp jitter (samples delivered in order:
sorted stamps) at 100 and 400 Hz, default parameters: the node counts no IMU gap and uses no more CPU than on the
clean stream; a real 0.3-s dropout in the same stream is found and bridged (test_node_driver_style.Driver).
Two nodes side by side: one on the clean stream, one on the jittered stream with the dropout, where the one gap counted must be the
dropout (its length and stamp from the node's log line): a gap counted for the jitter fails it (a third run of the
jittered stream without the dropout cost a third of the test for the same assertion).
400 Hz runs at the session level (test_gap_jitter.py); over DDS it costs the suite another 17 s of a worker (idle;
more on a shared 2-core machine), so it is run by hand (``test_host_stamp_jitter_over_dds(tmp_path, env, 400.0)``
with an isolated ROS env; on an idle machine, the nodes side by side: 0 gaps clean, the dropout the one gap of
0.308 s, node CPU 0.93-0.95x; docs/session.md)."""

import re
import time

import numpy as np
import pytest

from insalign_ros.cli.bringup import start_node, stop_nodes

from test_node_driver_style import ALIGN, MATCH_SETTLE_S, T0_NS, Driver

pytestmark = pytest.mark.ros


def _cpu_s(pid: int) -> float:
    """User + system CPU of a process [s] (/proc/<pid>/stat)."""
    import os
    with open(f"/proc/{pid}/stat") as fh:
        f = fh.read().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


class _Driver(Driver):
    """Driver with host-stamp jitter and IMU samples that are never sent (a dropout)."""

    imu_keep = None

    def imu(self, k):
        return Driver.imu(self, k)

    def stream(self, msgs_per_s=1000.0, fix_delay_s=0.15):
        pub = self.pub_imu
        keep = self.imu_keep

        class _Skip:  # publishes only the samples kept
            def __init__(self):
                self.k = 0

            def publish(self, msg):
                if keep is None or keep[self.k]:
                    pub.publish(msg)
                self.k += 1

        self.pub_imu = _Skip()
        try:
            Driver.stream(self, msgs_per_s, fix_delay_s)
        finally:
            self.pub_imu = pub


class _Run:
    """One alignment_node (renamed ``name``, its inputs on ``/<name>/...``) fed by its own driver."""

    def __init__(self, tmp_path, ros_env, name, d, jitter_s, drop):
        from insalign_ros.nodes.monitor import AlignmentMonitor

        self.d = d
        self.node = start_node(ALIGN, ros_env, log_dir=tmp_path, name=name, remaps={
            "__node": name, "imu/data": f"/{name}/imu/data_raw", "gps/fix": f"/{name}/fix"})
        self.mon = AlignmentMonitor(node_name=name, keep_poses=10)
        self.drv = _Driver(d, imu_topic=f"/{name}/imu/data_raw", fix_topic=f"/{name}/fix")
        t_host = np.sort(d.t_s + np.random.default_rng(3).normal(0.0, jitter_s, d.n)) if jitter_s > 0 else d.t_s
        self.drv.jitter_ns = np.round((t_host - d.t_s) * 1e9).astype(np.int64)
        if drop is not None:
            self.drv.imu_keep = ~((d.t_s > drop[0]) & (d.t_s < drop[1]))
        self.n_sent = int(self.drv.imu_keep.sum()) if drop is not None else d.n

    def up(self) -> bool:
        return self.drv.pub_imu.get_subscription_count() >= 1 and self.mon.diag_count >= 1

    def stream(self):
        # 3x real time: at 5x, under a loaded suite (two workers busy), the node fell behind and did not drain in 120 s
        self.drv.stream(msgs_per_s=self.d.imu_spec.rate_hz * 3.0)

    def drained(self, timeout_s: float) -> bool:
        return self.mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0
                                 and int(m.diag.get("imu_received", "0")) >= 0.99 * self.n_sent, timeout_s)

    def close(self):
        self.drv.close()
        self.mon.close()
        stop_nodes([self.node])


def _run_side_by_side(tmp_path, ros_env, d, drop):
    """The clean stream and the jittered one with the dropout, each to its own node, at the same time (one node
    after the other doubled the test's wall time; side by side both see the same machine load, so their CPU
    compares the better). Returns per run (gaps counted, node CPU from the first sample [s], node log)."""
    import threading

    runs = []
    try:
        runs.append(_Run(tmp_path, ros_env, "align_clean", d, 0.0, None))
        runs.append(_Run(tmp_path, ros_env, "align_jitter", d, 0.005, drop))
        end = time.monotonic() + 180.0
        while not all(r.up() for r in runs):
            assert time.monotonic() < end, "alignment_node did not come up"
            time.sleep(0.05)
        time.sleep(MATCH_SETTLE_S)
        cpu0 = [_cpu_s(r.node.popen.pid) for r in runs]
        threads = [threading.Thread(target=r.stream) for r in runs]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=300.0)
        for r in runs:
            with r.mon.lock:
                seen = {k: r.mon.diag.get(k) for k in ("imu_received", "buffered_imu", "imu_gaps", "state")}
            assert r.drained(180.0), f"sent {r.n_sent}: {seen}"
        time.sleep(1.0)
        out = []
        for r, c0 in zip(runs, cpu0):
            with r.mon.lock:
                diag = dict(r.mon.diag)
            out.append((int(diag["imu_gaps"]), _cpu_s(r.node.popen.pid) - c0, r.node.output()))
        return out
    finally:
        for r in runs:
            r.close()


@pytest.mark.timeout(600)
@pytest.mark.parametrize("rate_hz", [100.0])  # 400 Hz: see the module docstring
def test_host_stamp_jitter_over_dds(tmp_path, ros_env, rate_hz):
    from insalign_ros.sim.scenarios import make_scenario

    # 25 s of data (40 s before, 9 s more of the test): the dropout at 20 s, after the rate model's first 9 updates
    # (every 200 intervals, session/gaps.py) and 2,000 jittered intervals in which a jitter counted as a gap would show
    d = make_scenario("car", seed=4, duration_s=25.0, rate_hz=rate_hz, heading_deg=-120.0)
    (gaps_clean, cpu_clean, _), (gaps_jit, cpu_jit, log) = _run_side_by_side(tmp_path, ros_env, d, (20.0, 20.3))
    # the node's line per gap: "IMU gap of <length> s before <stamp of the sample after it>"
    found = [(float(a), float(b) - T0_NS * 1e-9) for a, b in re.findall(r"IMU gap of ([0-9.]+) s before ([0-9.]+)", log)]
    print(f"{rate_hz:g} Hz: gaps clean/jitter+0.3-s dropout {gaps_clean}/{gaps_jit} {found}; node CPU "
          f"clean {cpu_clean:.2f} s, jitter {cpu_jit:.2f} s ({cpu_jit / cpu_clean:.2f}x)")
    assert gaps_clean == 0 and gaps_jit == 1, (gaps_clean, gaps_jit)
    # the dropout: samples after 20.0 s and before 20.3 s not sent, so the sample after it is at 20.3 s (one
    # 10-ms interval later at most) and the gap between the stamps around it is 0.3 s plus up to two intervals and
    # the 5-ms jitter of either stamp (3 sigma each)
    assert len(found) == 1 and 0.25 < found[0][0] < 0.35 and 20.25 < found[0][1] < 20.36, found
    assert cpu_jit < 1.5 * cpu_clean + 1.0  # loose on a shared machine; the measured ratio is printed
