"""insalign_ros: strapdown INS initial alignment for ROS 2 Jazzy.

Python use (no ROS needed)::

    import insalign_ros as ia
    r = ia.align("ship", core="iekf", duration_s=120, init_mode="truth", init_rpy_error_deg=[10, 10, 60])
    print(r.t_s[-1], r.rpy_deg[-1], r.sigma3_deg[-1], r.aligned[-1], r.metrics.get("final_err_rpy_deg"))

``align(source, core=...)``: ``source`` is a bag path, a scenario name or a ScenarioData (``simulate``); the
result holds arrays of time, roll/pitch/yaw [deg], their 3-sigma, the aligned flag, and metrics when the source
has truth. The same :class:`AlignmentSession` runs inside ``alignment_node``.
"""

__version__ = "0.1.0"

__all__ = ["align", "read_bag", "simulate", "AlignmentSession", "SessionConfig", "core_names"]


def align(source, core: str | None = None, **kwargs):
    """See :func:`insalign_ros.session.offline.align` (``core`` None: SessionConfig's default, ``auto``)."""
    from .session.offline import align as _align

    return _align(source, core=core, **kwargs)


def read_bag(path, **kwargs):
    """A contract bag (or a foreign bag with Imu and NavSatFix topics) -> ScenarioData (io/bag.py)."""
    from .io.bag import read_bag as _read

    return _read(path, **kwargs)


def simulate(scenario: str, seed: int = 0, duration_s: float | None = None, **kwargs):
    """A simulated run (sim/scenarios.py) -> ScenarioData."""
    from .sim.scenarios import make_scenario

    return make_scenario(scenario, seed=seed, duration_s=duration_s, **kwargs)


def core_names() -> tuple:
    from .filters.registry import core_names as _names

    return _names()


def __getattr__(name):
    if name in ("AlignmentSession", "SessionConfig"):
        from . import session as _s
        from .session.config import SessionConfig
        from .session.session import AlignmentSession

        return {"AlignmentSession": AlignmentSession, "SessionConfig": SessionConfig}[name]
    raise AttributeError(name)
