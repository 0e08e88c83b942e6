"""docs/results.md is the page benchmarks/results.py generates: every section carries the command that makes it and the
machine load, and no table carries a date, a branch, a commit or a temporary path (the page is a maintained reference,
not a notebook)."""

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "results.md"


def _results():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import results
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return results


def test_every_section_has_its_command_and_load_and_no_notebook_traces():
    text = PAGE.read_text()
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    assert len(sections) >= 5
    for s in sections:
        title = s.splitlines()[0]
        assert "Command: `nice .venv/bin/python benchmarks/" in s or "Not run: the data" in s, title
        assert "Machine load" in s or "Not run: the data" in s, title
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), "a date in docs/results.md"
    assert "/tmp/" not in text and "/work/" not in text, "a machine-specific path in docs/results.md"
    assert not re.search(r"\b(branch|commit|main at) [0-9a-z]", text), "a branch or commit in docs/results.md"
    assert not re.search(r"\b(third|fourth|fifth) pass\b", text)


def test_no_page_of_the_documentation_is_a_lab_notebook():
    """docs/ is a reference for users: no dates, no branch names, no machine paths (the numbers carry their command
    and machine load instead); research/notebook/ keeps the history."""
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text()
        assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), f"a date in {page.name}"
        assert "/work/" not in text, f"a machine-specific path in {page.name}"
        assert not re.search(r"\bbranch [0-9a-z]", text), f"a branch name in {page.name}"


def test_clean_drops_the_benchmarks_command_lines_progress_and_temporary_paths():
    R = _results()
    out = R.clean("command: nice x\nseed 3 done\nwrote /tmp/abc/x.md\n## Head\n| a |\n| a |\nsame\nsame\n")
    assert "command:" not in out and "seed 3 done" not in out
    assert "/tmp/" not in out and "<tmp>" in out
    assert "### Head" in out  # one level below the section
    assert out.count("| a |") == 2 and out.count("same") == 1  # table rows kept, a repeated sentence once
    # every section names a benchmark that exists
    for s in R.SECTIONS:
        assert (ROOT / "benchmarks" / f"{s.module}.py").exists(), s.module
