#!/usr/bin/env bash
# The kill-and-restart launch test N times in a row (default 20) beside two busy loops (a loaded machine):
# the whole simulated cell SIGKILLed mid-job and restarted on the same journal must never weld a stud twice
# nor skip one. Stops at the first failure and names its log. After `bash tools/setup.sh`:
#   bash tools/kill_restart_soak.sh [N]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source ros2_ws/setup.bash
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((10 + $$ % 90))}"
runs="${1:-20}"
logs="$(mktemp -d)"
python3 -c "while True: pass" & busy1=$!
python3 -c "while True: pass" & busy2=$!
trap 'kill "$busy1" "$busy2" 2>/dev/null || true' EXIT
test_id=tests/launch/test_cell_ros.py::test_sim_cell_killed_mid_job_then_restarted_never_welds_a_stud_twice_nor_skips_one
for i in $(seq 1 "$runs"); do
  start=$(date +%s)
  if .venv/bin/python -m pytest "$test_id" -q -p no:cacheprovider > "$logs/run$i.log" 2>&1; then
    echo "run $i/$runs passed in $(( $(date +%s) - start )) s"
  else
    echo "run $i/$runs FAILED in $(( $(date +%s) - start )) s: $logs/run$i.log"
    exit 1
  fi
done
echo "$runs/$runs passed beside two busy loops"
