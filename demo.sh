#!/usr/bin/env bash
# Set everything up (idempotent) and run the main job: bash demo.sh [--out DIR]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
bash tools/setup.sh
# shellcheck disable=SC1091
source ros2_ws/setup.bash
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((10 + $$ % 90))}"
ros2 run stud_planner selfcheck
