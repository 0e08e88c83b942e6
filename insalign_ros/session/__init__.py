"""The alignment pipeline, ROS-free: one session behind the node, the offline runner and the benchmarks.

Inputs are pushed in arrival order and processed in stamp order (time-ordered buffer); the session owns
validation, initialisation, the core and its wrappers, the update schedule, the aligned flag and the status.
See docs/session.md.
"""

from . import auto as _auto  # noqa: F401,E402  registers the 'auto' core (issue 14) with filters.registry
