# Source this file (bash or zsh) to enter the fohssv environment:
#     source env.sh
# It activates the project venv (real ROS 2 Kilted from PyPI wheels), makes
# ament_index find the venv's message packages, keeps DDS discovery on this
# host, and overlays the colcon workspace ros2_ws/install if it is built.
# After it, `python -c 'import rclpy'` and the installed executables work.
if [ -n "${BASH_SOURCE:-}" ]; then
  _fohssv_here="${BASH_SOURCE[0]}"
elif [ -n "${ZSH_VERSION:-}" ]; then
  _fohssv_here="${(%):-%x}"
else
  _fohssv_here="$0"
fi
FOHSSV_ROOT="$(cd "$(dirname "$_fohssv_here")" && pwd)"
export FOHSSV_ROOT
unset _fohssv_here

if [ ! -x "$FOHSSV_ROOT/.venv/bin/python" ]; then
  echo "fohssv: no venv at $FOHSSV_ROOT/.venv; run 'make setup' first" >&2
  return 1 2>/dev/null || exit 1
fi

export VIRTUAL_ENV="$FOHSSV_ROOT/.venv"
case ":$PATH:" in *":$VIRTUAL_ENV/bin:"*) ;; *) export PATH="$VIRTUAL_ENV/bin:$PATH" ;; esac
# ament_index_python finds std_msgs & co. in the venv prefix only if it is listed here;
# colcon's install/setup.bash does not add it.
case ":${AMENT_PREFIX_PATH:-}:" in
  *":$VIRTUAL_ENV:"*) ;;
  *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;;
esac
# Kilted ignores ROS_LOCALHOST_ONLY; this keeps DDS traffic on the host unless the user says otherwise.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# ... and at the transport: Fast DDS binds UDP on loopback only (plus shared memory) with the
# package's profile, unless you chose a profile or FOHSSV_DDS_NETWORK=open (docs/ros.md).
if [ "${FOHSSV_DDS_NETWORK:-}" != "open" ] && [ -z "${FASTDDS_DEFAULT_PROFILES_FILE:-}" ] \
   && [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTDDS_DEFAULT_PROFILES_FILE="$FOHSSV_ROOT/src/fohssv_sim/config/fastdds_localhost.xml"
fi

if [ -f "$FOHSSV_ROOT/ros2_ws/install/setup.sh" ]; then
  # colcon's setup scripts fail under `set -u`: relax it while sourcing.
  case $- in *u*) _fohssv_u=1; set +u ;; *) _fohssv_u= ;; esac
  COLCON_CURRENT_PREFIX="$FOHSSV_ROOT/ros2_ws/install" . "$FOHSSV_ROOT/ros2_ws/install/setup.sh"
  [ -n "$_fohssv_u" ] && set -u
  unset _fohssv_u
fi
