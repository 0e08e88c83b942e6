"""Every example runs (examples never rot) and prints numbers inside the physical bounds of its scenario."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args, timeout=300) -> str:
    out = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_align_scenario_example():
    text = _run("examples/align_scenario.py", "--duration", "60")
    err = [float(x) for x in re.search(r"final roll/pitch/yaw error \[(.*?)\]", text).group(1).split(",")]
    s3 = [float(x) for x in re.search(r"3-sigma \[(.*?)\]", text).group(1).split(",")]
    assert all(abs(e) < s for e, s in zip(err, s3)) and abs(err[2]) < 1.0, text


def test_align_bag_example_unknown_heading(tmp_path):
    text = _run("examples/align_bag.py", str(tmp_path))
    m = re.search(r"final yaw (\S+) deg \(truth (\S+) deg\), 3-sigma (\S+) deg, aligned (\w+)", text)
    yaw, truth, s3 = (float(m.group(i)) for i in (1, 2, 3))
    assert abs((yaw - truth + 180) % 360 - 180) < min(s3, 1.0) and m.group(4) == "True", text


def test_every_example_has_a_test():
    tested = {"align_scenario.py", "align_bag.py", "make_import_example.py"}  # the last: test_import.py
    assert {p.name for p in (ROOT / "examples").glob("*.py")} <= tested
