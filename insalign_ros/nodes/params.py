"""alignment_node's parameters: the table (name, default, description, read-only), every numeric parameter's range,
and the one validation function the start-up and the run-time changes both go through (docs/nodes.md,
"Parameters"). No node here: :func:`check_value` and :func:`unknown_parameters` are plain functions (tested
in-process for every parameter of every core, test_node_param_ranges.py).
"""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from ..session import catalog

#: every node parameter but the core's: name -> ParamSpec, from the configuration's field metadata (SessionConfig,
#: NodeConfig, the flag criteria; session/catalog.py). Nothing here restates a description or a bound.
SPECS = {p.name: p for p in catalog.node_parameter_specs()}
#: session parameters the node exposes under the same names (SessionConfig has the meaning): name -> description
SESSION_DOC = {n: p.doc for n, p in SPECS.items() if p.group == "session"}
#: the node's own parameters and the read-only session ones: name -> (default, description, read_only)
NODE_PARAMS = {n: (p.default, p.doc, p.read_only) for n, p in SPECS.items() if p.group == "node"}
#: the range of every numeric parameter whose field metadata gives one (node, session, flag, every core): name ->
#: (lo, hi), inclusive; the others get DEFAULT_RANGE (a non-negative quantity) or INT_RANGE
RANGES = {**{n: tuple(md["range"]) for n, md in catalog.core_field_metadata().items() if md.get("range")},
          **{n: p.range for n, p in SPECS.items() if p.range is not None}}
DEFAULT_RANGE = catalog.DEFAULT_RANGE


def is_numeric(default) -> bool:
    return isinstance(default, (int, float)) and not isinstance(default, bool)


def range_of(name: str, default) -> tuple | None:
    """The inclusive range of a numeric parameter (None: not a numeric scalar)."""
    if not is_numeric(default):
        return None
    return RANGES.get(name) or catalog.range_of(name, default)


def descriptor(name: str, default, text: str, read_only: bool) -> ParameterDescriptor:
    """A description, and a range for every numeric parameter (what `ros2 param describe` shows)."""
    d = ParameterDescriptor(description=text, read_only=read_only)
    rng = range_of(name, default)
    if isinstance(default, float):
        lo, hi = rng
        d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
        d.additional_constraints = f"range [{lo:g}, {hi:g}]"
    elif rng is not None:
        lo, hi = rng
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        d.additional_constraints = f"range [{lo}, {hi}]"
    return d


def coerce(default, value):
    """An int for a float and a list of ints for a list of floats become floats; other type changes: ValueError."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, (list, tuple)) and isinstance(value, (list, tuple)):
        if all(isinstance(x, float) for x in default):
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
                raise ValueError(f"wrong type: expected a list of numbers, got {list(value)!r}")
            return [float(x) for x in value]
        return list(value)
    if type(value) is not type(default):
        raise ValueError(f"wrong type: expected {type(default).__name__}, got {value!r} ({type(value).__name__})")
    return value


def check_value(name: str, default, value):
    """``value`` for parameter ``name`` (declared default ``default``) coerced as :func:`coerce` does and checked
    against its range; ValueError with one line naming the parameter, the value and the range otherwise."""
    try:
        v = coerce(default, value)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    rng = range_of(name, default)
    if rng is not None:
        lo, hi = rng
        if not (lo <= v <= hi):  # NaN fails too
            raise ValueError(f"{name}: value {v!r} outside its range [{lo:g}, {hi:g}]")
    return v


def core_parameter_owners() -> dict:
    """parameter name -> the cores that have it (for naming another core's parameter)."""
    out: dict = {}
    for core in catalog.core_names():
        for name in catalog.core_defaults(core):
            out.setdefault(name, []).append(core)
    return out


def rename_deprecated(overrides: dict, declared_core_params) -> list[str]:
    """Parameters given at start (``overrides``: name -> rclpy Parameter) under a deprecated name
    (catalog.DEPRECATED_ALIASES, the one table) are renamed in place to the name the core declares, the value
    scaled by the table's factor; one warning line each. Old and new name with different values: ValueError."""
    from rclpy.parameter import Parameter

    lines = []
    for old in [n for n in overrides if n in catalog.DEPRECATED_ALIASES]:
        new, factor = catalog.DEPRECATED_ALIASES[old]
        if new not in declared_core_params:
            continue  # not this core's: unknown_parameters names it
        value = overrides.pop(old).value
        if factor != 1.0 and is_numeric(value):
            value = float(value) * factor
        if new in overrides and overrides[new].value != value:
            raise ValueError(f"{old}: deprecated name of {new!r}, given both with different values")
        overrides[new] = Parameter(new, value=value)
        lines.append(catalog.deprecation_message(old))
    return lines


def unknown_parameters(given, declared, core: str) -> list[str]:
    """One warning line per parameter ``given`` (set at start: a file or -p) that the node does not declare: a
    misspelling, or a parameter of another core than ``core``."""
    owners = None
    lines = []
    for name in sorted(set(given) - set(declared)):
        if name == "use_sim_time" or name.startswith("qos_overrides.") or name == "start_type_description_service":
            continue
        owners = owners if owners is not None else core_parameter_owners()
        if name in owners:
            lines.append(f"parameter {name!r} is not a parameter of core {core!r} (it belongs to "
                         f"{', '.join(owners[name])}): ignored")
        else:
            lines.append(f"unknown parameter {name!r}: ignored (misspelled?)")
    return lines
