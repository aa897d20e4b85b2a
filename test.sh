#!/usr/bin/env bash
# Set everything up (idempotent) and run the whole test suite: bash test.sh [pytest args]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
bash tools/setup.sh
# shellcheck disable=SC1091
source ros2_ws/setup.bash
# Each run talks DDS in a domain of its own, on loopback only (see tests/conftest.py).
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((10 + $$ % 90))}"
python -m pytest tests "$@"
