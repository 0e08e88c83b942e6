"""Generated, never restated (issue 23 item 4): config/alignment_node.yaml (values and comments), docs/nodes.md's
parameter tables and the node's parameter descriptors all come from the configuration's field metadata
(session/config.py SessionConfig and NodeConfig, the cores' config dataclasses, the flag criteria; session/catalog.py).
A shipped file that differs from the generated one fails here with the diff and the command that regenerates it.
"""

import difflib
from dataclasses import fields

import pytest

from insalign_ros.session import catalog

REGENERATE = "python -m insalign_ros.session.catalog --write-yaml --write-docs"


@pytest.mark.parametrize("rel", ["config/alignment_node.yaml", "docs/nodes.md"]
                         + [f"config/{core}.yaml" for core in catalog.CORE_YAMLS])
def test_shipped_file_is_the_generated_one(rel):
    new, shipped = catalog.generated_files()[rel]
    if new != shipped:
        diff = "".join(difflib.unified_diff(shipped.splitlines(True), new.splitlines(True), rel, rel + " (generated)"))
        pytest.fail(f"{rel} differs from the one generated from the configuration's metadata; regenerate with\n"
                    f"    {REGENERATE}\n{diff}")


def test_every_node_parameter_has_a_description_and_every_number_a_range():
    specs = catalog.node_parameter_specs()
    assert len({p.name for p in specs}) == len(specs)
    for p in specs:
        assert p.doc, p.name
        numeric = isinstance(p.default, (int, float)) and not isinstance(p.default, bool)
        assert (p.range is not None) == numeric, p.name
        if numeric:
            assert p.range[0] <= p.default <= p.range[1], p.name
    for core in catalog.core_names():
        for p in catalog.core_parameter_specs(core, catalog.DEFAULT_IMU_GRADE):
            if p.range is not None:
                assert p.range[0] <= p.default <= p.range[1], (core, p.name)


def test_one_name_means_one_thing_in_every_core():
    """Metadata given for a field name in two core config classes agrees (the same name, the same range)."""
    from insalign_ros.filters import registry

    seen: dict = {}
    for core in catalog.core_names():
        for f in fields(registry.CORES[core][1]):
            rng = f.metadata.get("range")
            if rng is not None:
                assert seen.setdefault(f.name, rng) == rng, (core, f.name)


def test_the_node_declares_the_generated_descriptors():
    """The node's parameter table (nodes/params.py) is the catalog's: no description or bound of its own."""
    from insalign_ros.nodes import params

    for p in catalog.node_parameter_specs():
        if p.group == "session":
            assert params.SESSION_DOC[p.name] == p.doc
        elif p.group == "node":
            assert params.NODE_PARAMS[p.name] == (p.default, p.doc, p.read_only)
        if p.range is not None:
            assert params.range_of(p.name, p.default) == p.range, p.name
        d = params.descriptor(p.name, p.default, p.doc, p.read_only)
        assert d.description == p.doc and d.read_only == p.read_only
    for core in catalog.core_names():
        for p in catalog.core_parameter_specs(core):
            if p.name not in params.SPECS:  # a session field shared with the core: the node declares the session's
                assert params.range_of(p.name, p.default) == p.range, (core, p.name)


def test_session_refuses_what_the_node_range_refuses():
    """A session value outside its field's range is refused offline too (one range, both doors)."""
    from insalign_ros.session.config import SessionConfig

    with pytest.raises(ValueError, match="max_rate_rad_s"):
        SessionConfig.from_dict({"max_rate_rad_s": 5000.0})
    with pytest.raises(ValueError, match="unknown_heading_hypotheses"):
        SessionConfig.from_dict({"unknown_heading_hypotheses": 40})
