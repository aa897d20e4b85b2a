#!/usr/bin/env bash
# Set everything up (idempotent) and run the main job: the simulated weld cell on the bundled
# dome drawing, scored against the scene truth. Output in out/demo/. Args go to the demo:
#   bash demo.sh [--out DIR] [--no-hmi] [--time-scale 1.0]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
bash tools/setup.sh
# shellcheck disable=SC1091
source ros2_ws/setup.bash
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((10 + $$ % 90))}"
ros2 run stud_planner selfcheck --timeout 30
exec ros2 run stud_planner demo "$@"
