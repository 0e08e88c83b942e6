"""What the layers above the session (the node, the command-line tools) may know about the cores and IMU grades:
their names, their parameters and defaults, and whether a configuration can run. The node imports nothing from
filters/ (.importlinter); this module is its one door.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from ..filters import registry
from ..filters.imu_grade import (DEFAULT_IMU_GRADE, DEPRECATED_ALIASES, GRADE_FIELDS, GRADES, apply_aliases,
                                 deprecation_message, grade_params)
from . import auto as _auto  # noqa: F401  the composed core 'auto' registers itself with filters.registry

__all__ = ["DEFAULT_IMU_GRADE", "DEPRECATED_ALIASES", "GRADES", "deprecation_message", "backtracking_core", "check_core_config", "core_names", "core_defaults",
           "grade_defaults"]


def core_names() -> tuple[str, ...]:
    return registry.core_names()


def _config_class(core: str):
    if core not in core_names():
        raise ValueError(f"core: unknown core {core!r}; choose one of {sorted(core_names())}")
    return registry.CORES[core][1]


def core_defaults(core: str) -> dict:
    """Every parameter of ``core`` with its default (ValueError: unknown core)."""
    return _config_class(core)().to_dict()


def grade_defaults(grade, core: str) -> dict:
    """The parameters of ``core`` an IMU grade (a name, or an ImuGrade) sets (ValueError: unknown grade)."""
    return grade_params(grade, _config_class(core))


#: cores that run backtracking passes, under the name of the backtrackable core the session builds for them
BACKTRACKING_CORES = {"earth_iekf": "earth_iekf", "liekf": "liekf_backtrack", "liekf_backtrack": "liekf_backtrack"}


def backtracking_core(core: str, core_params: dict) -> str:
    """The core the session builds for ``core`` when backtracking passes are asked for (ValueError: none can)."""
    if core not in BACKTRACKING_CORES or int(core_params.get("yaw_hypotheses", 1)) > 1:
        raise ValueError(f"backtrack_passes > 0 needs one filter of a core with backward propagation "
                         f"({', '.join(BACKTRACKING_CORES)}; yaw_hypotheses 1); got core {core!r}, "
                         f"yaw_hypotheses {core_params.get('yaw_hypotheses', 1)}")
    return BACKTRACKING_CORES[core]


#: session fields a core config may have under the same name: the session's value is the one (an explicit core
#: parameter of that name still wins), so ``unknown_heading_hypotheses`` is one hypothesis count for the session's
#: initialiser and the auto core alike
SHARED_WITH_CORES = ("unknown_heading_hypotheses",)


def resolve_core_params(config, core_params: dict | None = None) -> dict:
    """The core parameters a session runs (``config`` a SessionConfig): the IMU grade's noise and bias fields, the
    session's shared fields (:data:`SHARED_WITH_CORES`), then the explicit ``core_params`` (deprecated names mapped,
    filters/imu_grade.DEPRECATED_ALIASES)."""
    names = {f.name for f in fields(_config_class(config.core))}
    values = config.to_dict()
    shared = {n: values[n] for n in SHARED_WITH_CORES if n in names}
    return registry.resolve_core_params(config.imu_grade, config.core, {**shared, **apply_aliases(dict(core_params or {}))})


def check_core_config(config, core_params: dict) -> None:
    """ValueError (with the reason) when the session configuration ``config`` and the core parameters cannot run:
    a bad core parameter, or backtracking asked of a core without backward propagation. The node and the offline
    tools refuse the same configurations through this one check."""
    registry.make_config(config.core, core_params)
    if config.backtrack_passes > 0:
        backtracking_core(config.core, core_params)


# ------------------------------------------------------------------ parameter specs (generated, never restated)
#: a number without a range in its field's metadata: a non-negative physical quantity / a non-negative integer
DEFAULT_RANGE = (0.0, 1e15)
INT_RANGE = (0, 2**31 - 1)
#: the aligned-flag criteria (session/flag.py AlignedCriteria, node parameters ``aligned.<name>``): description and
#: range. The flag's yaw_3sigma_deg is THE aligned threshold (docs/imu_grades.md, "One name per number")
CRITERIA_META = {
    "roll_pitch_3sigma_deg": ("3-sigma roll/pitch bound of the aligned flag [deg]", (1e-6, 180.0)),
    "level_floor_factor": ("the roll/pitch bound is at least this many times the level floor of the declared "
                           "accelerometer bias, 3 atan(acc_bias / g) (0: off)", (0.0, 100.0)),
    "yaw_3sigma_deg": ("3-sigma yaw bound of the aligned flag [deg]: THE aligned threshold (a core's own "
                       "status_yaw_3sigma_deg is not the flag)", (1e-6, 360.0)),
    "nis_window": ("NIS window [updates] (0: off)", (0, 10000)),
    "nis_min_updates": ("the NIS test runs once the window holds this many updates (the band of those)", (1, 10000)),
    "nis_alpha": ("two-sided chi-square probability", (1e-12, 0.999999)),
    "nis_alpha_drop": ("once up: the flag drops on the NIS test only outside this wider band (hysteresis)",
                       (1e-12, 0.999999)),
    "nis_lower_check": ("also fail on a too-small NIS sum", None),
    "hold_s": ("criteria must hold this long [s]", (0.0, 3600.0)),
    "max_update_age_s": ("last accepted update at most this old [s]", (1e-3, 3600.0)),
}


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: what ``ros2 param describe`` shows, the YAML comment and the docs row say."""

    name: str
    default: object
    doc: str
    read_only: bool
    range: tuple | None
    group: str  # "node", "session", "aligned" or "core"


def range_of(name: str, default, metadata_range=None) -> tuple | None:
    """The inclusive range of a numeric parameter (None: not a numeric scalar)."""
    if not isinstance(default, (int, float)) or isinstance(default, bool):
        return None
    if metadata_range is not None:
        return tuple(metadata_range)
    return DEFAULT_RANGE if isinstance(default, float) else INT_RANGE


def _spec(f, default, group: str, name: str | None = None) -> ParamSpec:
    md = f.metadata
    return ParamSpec(name or f.name, default, md.get("doc", ""), bool(md.get("read_only", False)),
                     range_of(f.name, default, md.get("range")), group)


def node_parameter_specs() -> list[ParamSpec]:
    """Every node parameter that is not a core parameter, in declaration order: core and imu_grade, the node's own
    (NodeConfig), the session's (SessionConfig fields the node exposes) and the aligned-flag criteria."""
    from .config import NodeConfig, SessionConfig
    from .flag import AlignedCriteria

    s, n = SessionConfig().to_dict(), asdict(NodeConfig())
    sf = {f.name: f for f in fields(SessionConfig)}
    out = [_spec(sf[k], s[k], "node") for k in ("core", "imu_grade")]
    out += [_spec(f, n[f.name], "node") for f in fields(NodeConfig)]
    out += [_spec(f, s[f.name], "session") for f in fields(SessionConfig)
            if f.metadata.get("node", True) and f.name not in ("core", "imu_grade")]
    crit = AlignedCriteria().to_dict()
    for f in fields(AlignedCriteria):
        doc, rng = CRITERIA_META[f.name]
        v = crit[f.name]
        out.append(ParamSpec(f"aligned.{f.name}", v, doc, False, range_of(f.name, v, rng), "aligned"))
    return out


def core_field_metadata() -> dict:
    """field name -> its metadata, over every registered core's config class (one name means one thing in every
    core: the first field that carries a description or a range gives them)."""
    out: dict = {}
    for core in core_names():
        for f in fields(_config_class(core)):
            md = f.metadata
            if md.get("doc") or md.get("range") is not None:
                have = out.setdefault(f.name, {})
                for k in ("doc", "range"):
                    if md.get(k) not in (None, "") and have.get(k) in (None, ""):
                        have[k] = md[k]
    return out


def core_parameter_specs(core: str, grade=None) -> list[ParamSpec]:
    """The parameters of ``core`` as the node declares them: defaults from the IMU grade where it sets them."""
    meta = core_field_metadata()
    own = {f.name: f.metadata for f in fields(_config_class(core))}
    from_grade = grade_defaults(grade, core) if grade is not None else {}
    out = []
    for name, default in core_defaults(core).items():
        md = {k: v for k, v in meta.get(name, {}).items() if v not in (None, "")}
        md.update({k: v for k, v in own[name].items() if k in ("doc", "range") and v not in (None, "")})
        doc = md.get("doc") or f"{core} core parameter (config/{core}.yaml)"
        if name in from_grade:
            default = from_grade[name]
            doc = f"{doc}; default from imu_grade {grade} (docs/imu_grades.md)"
        out.append(ParamSpec(name, default, doc, False, range_of(name, default, md.get("range")), "core"))
    return out


# ------------------------------------------------------------------ generated files
YAML_HEADER = """\
# Common parameters of alignment_node (ROS 2 parameter file). Load it together with config/<core>.yaml:
#   ros2 run insalign_ros alignment_node --ros-args --params-file config/alignment_node.yaml --params-file config/liekf.yaml
# Units are in the names; docs/nodes.md and docs/session.md explain each (ros2 param describe shows the same text
# and ranges). GENERATED from the configuration's field metadata: do not edit, run
#   python -m insalign_ros.session.catalog --write-yaml
# (test/test_config_generated.py fails when this file differs).
"""
DOCS_BEGIN = "<!-- BEGIN parameter table: generated by `python -m insalign_ros.session.catalog --write-docs` -->"
DOCS_END = "<!-- END parameter table -->"


def _yaml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v) or math.isinf(v):
            return ".nan" if math.isnan(v) else (".inf" if v > 0 else "-.inf")
        mant, e, exp = repr(v).partition("e")
        return f"{mant}.0e{exp}" if e and "." not in mant else repr(v)  # 1.0e-06: a float to YAML 1.1
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_yaml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return "''" if v == "" else v
    return repr(v)


def alignment_node_yaml() -> str:
    """config/alignment_node.yaml: every node and session parameter but ``core`` with its default and description."""
    lines = [YAML_HEADER.rstrip("\n"), "/**:", "  ros__parameters:"]
    crit = []
    for p in node_parameter_specs():
        if p.name == "core":
            continue
        if p.group == "aligned":
            crit.append(p)
            continue
        lines.append(f"    {p.name}: {_yaml_value(p.default)}  # {p.doc}")
    lines.append("    aligned:  # the aligned-flag criteria (insalign_ros/session/flag.py, docs/nodes.md)")
    for p in crit:
        lines.append(f"      {p.name.split('.', 1)[1]}: {_yaml_value(p.default)}  # {p.doc}")
    return "\n".join(lines) + "\n"


#: the cores whose defaults ship as config/<core>.yaml (generated; config/<core>_navgrade.yaml pin a grade by hand)
CORE_YAMLS = ("liekf", "pi_liekf", "iekf", "ekf", "earth_iekf", "pkf", "ekf10", "coarse", "auto")


def core_yaml(core: str) -> str:
    """config/<core>.yaml: the core's defaults but the IMU-grade fields, commented from the fields' metadata."""
    cls = _config_class(core)
    first = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
    grade = [n for n in core_defaults(core) if n in GRADE_FIELDS]
    lines = [f"# {core}: the defaults of {cls.__module__}.{cls.__name__}. {first}",
             "# Units are in the names. GENERATED from the configuration's field metadata: do not edit, run",
             "#   python -m insalign_ros.session.catalog --write-yaml",
             "# Load: make_core(p.pop('core'), p) with p = ros__parameters; the node: with config/alignment_node.yaml.",
             "/**:", "  ros__parameters:", f"    core: {core}"]
    if grade:
        lines += [f"    # IMU noise and bias priors ({', '.join(grade)}):",
                  "    # from imu_grade (config/alignment_node.yaml, docs/imu_grades.md); a value set here overrides the grade"]
    own = {f.name: f.metadata.get("doc", "") for f in fields(cls)}
    for p in core_parameter_specs(core):
        if p.name in GRADE_FIELDS:
            continue
        doc = own.get(p.name) or ""
        lines.append(f"    {p.name}: {_yaml_value(p.default)}" + (f"  # {doc}" if doc else ""))
    return "\n".join(lines) + "\n"


def _md(text) -> str:
    return str(text).replace("|", "\\|")


def _md_range(rng) -> str:
    return "" if rng is None else f"[{rng[0]:g}, {rng[1]:g}]"


def nodes_md_table() -> str:
    """docs/nodes.md's parameter tables (node, session, flag; then every core parameter and its cores)."""
    out = [DOCS_BEGIN, "", "| parameter | default | range | read-only | description |", "|---|---|---|---|---|"]
    for p in node_parameter_specs():
        out.append(f"| `{p.name}` | `{_md(_yaml_value(p.default))}` | {_md_range(p.range)} | "
                   f"{'yes' if p.read_only else ''} | {_md(p.doc)} |")
    out += ["", "Core parameters (declared for the chosen core only; the IMU-grade fields default to the grade's "
                "values, docs/imu_grades.md):", "", "| parameter | cores | range | description |", "|---|---|---|---|"]
    rows: dict = {}
    for core in core_names():
        for p in core_parameter_specs(core):
            rows.setdefault(p.name, [p, []])[1].append(core)
    for name in sorted(rows):
        p, cores = rows[name]
        doc = p.doc if not p.doc.endswith(f"(config/{cores[0]}.yaml)") else "see config/<core>.yaml"
        out.append(f"| `{name}` | {', '.join(cores)} | {_md_range(p.range)} | {_md(doc)} |")
    out += ["", DOCS_END]
    return "\n".join(out)


def _root():
    from pathlib import Path

    return Path(__file__).resolve().parents[2]


def generated_files() -> dict:
    """path (relative to the repository) -> (the generated text, the text as shipped)."""
    root = _root()
    yaml_path, docs_path = root / "config" / "alignment_node.yaml", root / "docs" / "nodes.md"
    docs = docs_path.read_text()
    if DOCS_BEGIN in docs and DOCS_END in docs:
        i, j = docs.index(DOCS_BEGIN), docs.index(DOCS_END) + len(DOCS_END)
        new_docs = docs[:i] + nodes_md_table() + docs[j:]
    else:
        new_docs = docs + "\n" + nodes_md_table() + "\n"
    out = {"config/alignment_node.yaml": (alignment_node_yaml(), yaml_path.read_text()),
           "docs/nodes.md": (new_docs, docs)}
    for core in CORE_YAMLS:
        path = root / "config" / f"{core}.yaml"
        out[f"config/{core}.yaml"] = (core_yaml(core), path.read_text() if path.exists() else "")
    return out


def main(argv=None) -> int:
    import argparse
    import difflib

    ap = argparse.ArgumentParser(prog="python -m insalign_ros.session.catalog",
                                 description="Write (or check) the files generated from the configuration's metadata")
    ap.add_argument("--write-yaml", action="store_true", help="write config/alignment_node.yaml")
    ap.add_argument("--write-docs", action="store_true", help="write the parameter table of docs/nodes.md")
    ap.add_argument("--check", action="store_true", help="print the diff of every file that differs; exit 1")
    a = ap.parse_args(argv)
    gen = generated_files()
    which = {rel: (a.write_docs if rel.endswith(".md") else a.write_yaml) for rel in gen}
    rc = 0
    for rel, (new, old) in gen.items():
        if which[rel]:
            (_root() / rel).write_text(new)
            print(f"wrote {rel}")
        elif a.check and new != old:
            rc = 1
            print("".join(difflib.unified_diff(old.splitlines(True), new.splitlines(True), rel, rel + " (generated)")))
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
