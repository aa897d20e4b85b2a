# Enter the project's environment:   source ros2_ws/setup.bash
# Puts the venv (ROS 2 Jazzy wheels, our `ros2` entry), the ROS environment and the built
# workspace on the path. Run `bash tools/setup.sh` once before (the README's commands do).
_stud_ws="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
_stud_venv="${STUD_VENV:-$(dirname "$_stud_ws")/.venv}"
if [ ! -f "$_stud_venv/bin/activate" ] || [ ! -f "$_stud_ws/install/setup.bash" ]; then
  echo "ros2_ws/setup.bash: the environment is not built yet; run: bash tools/setup.sh" >&2
  unset _stud_ws _stud_venv
  return 1 2>/dev/null || exit 1
fi
# colcon's and venv's scripts read unset variables: allow that while sourcing them, even
# when the caller runs under `set -u`, and restore the caller's setting afterwards.
case $- in *u*) _stud_nounset=1; set +u;; *) _stud_nounset=0;; esac
# shellcheck disable=SC1091
source "$_stud_venv/bin/activate"
case ":${AMENT_PREFIX_PATH:-}:" in *":$_stud_venv:"*) ;; *) export AMENT_PREFIX_PATH="$_stud_venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}";; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":$_stud_venv:"*) ;; *) export CMAKE_PREFIX_PATH="$_stud_venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}";; esac
# shellcheck disable=SC1091
source "$_stud_ws/install/setup.bash"
# DDS stays on this machine unless the user says otherwise (a weld cell's camera and arm
# are on the cell network: set ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET there).
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export PYTHONUNBUFFERED=1
# Whole RGB-D frames through shared memory (see config/fastdds.xml); a user's own profile wins.
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_stud_ws/config/fastdds.xml}"
[ "$_stud_nounset" = 1 ] && set -u
unset _stud_ws _stud_venv _stud_nounset
