"""A registered core under another name whose instances a benchmark can read after ``ia.align`` (the session builds
and closes its cores; a benchmark that reports a core's own history, e.g. the PI-LIEKF's LMI solves, keeps them)."""

from __future__ import annotations


def recorded_class(base: type, record: list, **init_kwargs) -> type:
    """A subclass of the core class ``base`` whose instances, built with ``init_kwargs`` besides their configuration,
    are appended to ``record``."""

    class Recorded(base):
        def __init__(self, cfg):
            super().__init__(cfg, **init_kwargs)
            record.append(self)

    Recorded.__name__ = Recorded.__qualname__ = f"Recorded{base.__name__}"
    return Recorded


def register_recorded(alias: str, base: str, record: list, **init_kwargs) -> str:
    """Register ``alias``: the core ``base`` (its class and config class), built with ``init_kwargs`` besides its
    configuration, each instance appended to ``record``. Returns ``alias``. Only benchmarks and research use it; the
    product registers nothing."""
    from insalign_ros.filters import registry

    registry.register(alias, recorded_class(registry.core_class(base), record, **init_kwargs), registry.CORES[base][1])
    return alias


def with_history(record: list) -> list:
    """The recorded cores that ran."""
    return [c for c in record if getattr(c, "lmi_history", None)]
