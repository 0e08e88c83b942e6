"""A registered core under another name whose instances a benchmark can read after ``ia.align`` (the session builds
and closes its cores; a benchmark that reports a core's own history, e.g. the PI-LIEKF's LMI solves, keeps them)."""

from __future__ import annotations


def register_recorded(alias: str, base: str, record: list, factory=None) -> str:
    """Register ``alias``: the core ``base`` (its config class; its own factory, or ``factory(cfg)``), each instance
    appended to ``record``. Returns ``alias``. Only benchmarks and research use it; the product registers nothing."""
    from insalign_ros.filters import registry

    registry.make_config(base)  # a lazily registered core registers itself here
    base_factory, config_class = registry.CORES[base]
    build = factory or base_factory

    def make(cfg):
        core = build(cfg)
        record.append(core)
        return core

    registry.register(alias, make, config_class)
    return alias


def with_history(record: list) -> list:
    """The recorded cores that ran (the session also builds a probe core that never runs)."""
    return [c for c in record if getattr(c, "lmi_history", None)]
