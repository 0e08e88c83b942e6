# Sourced by scripts/test and scripts/demo: create the virtualenv and install what is missing.
# Quick when everything is there: pip (and the numba warm-up after it) runs only when requirements.txt or setup.py
# changed. python -m insalign_ros.session.warmup compiles the kernels again by hand (e.g. after NUMBA_CACHE_DIR moved).
set -euo pipefail
INSALIGN_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
INSALIGN_VENV="${INSALIGN_VENV:-$INSALIGN_ROOT/.venv}"
PYTHON="${PYTHON:-python3}"

# CPython 3.11-3.14: the ROS 2 Jazzy PyPI wheels exist for 3.10-3.14 (Linux x86_64 only), but the pinned numpy 2.4 and
# scipy 1.17 need Python >= 3.11. An apt ROS 2 Jazzy (Ubuntu 24.04) has its own path: README, requirements-apt.txt.
if [ "$(uname -m)" != "x86_64" ] || [ "$(uname -s)" != "Linux" ]; then
  echo "insalign_ros's virtualenv needs Linux x86_64: the ROS 2 Jazzy PyPI wheels (ros-jazzy-rclpy ...) exist for no other platform; found $(uname -s) $(uname -m). With ROS 2 Jazzy from apt, see README (requirements-apt.txt)" >&2
  exit 2
fi
if ! "$PYTHON" -c 'import sys; sys.exit(0 if (3, 11) <= sys.version_info[:2] <= (3, 14) else 1)'; then
  echo "insalign_ros needs CPython 3.11-3.14 (numpy==2.4.6 and scipy==1.17.1 in requirements.txt need Python >= 3.11; the ROS 2 Jazzy wheels stop at 3.14); found: $("$PYTHON" --version 2>&1). Set PYTHON=python3.11 (or newer)" >&2
  exit 2
fi
if [ ! -x "$INSALIGN_VENV/bin/python" ]; then
  echo "[insalign] creating virtualenv $INSALIGN_VENV" >&2
  if ! "$PYTHON" -m venv "$INSALIGN_VENV" 2>/dev/null; then
    echo "[insalign] python3 -m venv failed; on Debian/Ubuntu: sudo apt-get install python3-venv" >&2
    exit 2
  fi
fi
stamp="$INSALIGN_VENV/.insalign-installed"
want="$(cat "$INSALIGN_ROOT/requirements.txt" "$INSALIGN_ROOT/setup.py" "$INSALIGN_ROOT/setup.cfg" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[insalign] installing pinned requirements into $INSALIGN_VENV (about a minute on a cold machine)" >&2
  "$INSALIGN_VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip
  "$INSALIGN_VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$INSALIGN_ROOT/requirements.txt"
  "$INSALIGN_VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$INSALIGN_ROOT"
  # compile the numba kernels now, once, so that the first node, demo or test finds a warm cache (docs/install.md,
  # "First run"); a failure here is not fatal: the kernels then compile on first use
  echo "[insalign] compiling the numba kernels of every core (about a minute on a cold machine, once)" >&2
  # (in two processes at once: half the wall time of one on 2 cores, session/warmup.py GROUPS)
  (cd "$INSALIGN_ROOT" && "$INSALIGN_VENV/bin/python" -m insalign_ros.session.warmup --jobs 2) \
    || echo "[insalign] warm-up failed; the kernels compile on first use instead" >&2
  echo "$want" > "$stamp"
fi
export PATH="$INSALIGN_VENV/bin:$PATH"
export VIRTUAL_ENV="$INSALIGN_VENV"
# Only needed for ament-index look-ups and colcon overlays; rclpy itself needs nothing.
export AMENT_PREFIX_PATH="$INSALIGN_VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export MPLBACKEND="${MPLBACKEND:-Agg}"
