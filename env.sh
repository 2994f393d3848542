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
# DDS stays on this host unless you say otherwise (Kilted ignores ROS_LOCALHOST_ONLY), at
# the transport too: Fast DDS binds UDP on loopback only (plus shared memory) with the
# package's profile, unless you chose a profile or FOHSSV_DDS_NETWORK=open (README.md).
# With that profile the discovery range is SUBNET, as the fohssv nodes hand it to rcl:
# rmw_fastrtps adds a UDP transport on every interface of its own for LOCALHOST (your own
# rclpy process would bind 0.0.0.0 and the external address and be discovered late); the
# profile's loopback-only transports keep SUBNET discovery on this machine. Without the
# profile the range is LOCALHOST. A range or a profile you exported yourself is kept (the
# profile and a LOCALHOST env.sh exported itself on an earlier `source` are not yours, and
# follow FOHSSV_DDS_NETWORK when you source it again: _FOHSSV_SET_*).
_fohssv_range="${ROS_AUTOMATIC_DISCOVERY_RANGE:-}"
if [ "$_fohssv_range" = LOCALHOST ] && [ "${_FOHSSV_SET_RANGE:-}" = LOCALHOST ]; then
  _fohssv_range=
fi
_fohssv_profile="${FASTDDS_DEFAULT_PROFILES_FILE:-}"
if [ -n "$_fohssv_profile" ] && [ "$_fohssv_profile" = "${_FOHSSV_SET_PROFILE:-}" ]; then
  _fohssv_profile=
  unset FASTDDS_DEFAULT_PROFILES_FILE
fi
if [ "${FOHSSV_DDS_NETWORK:-}" != "open" ] && [ -z "$_fohssv_profile" ] \
   && [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTDDS_DEFAULT_PROFILES_FILE="$FOHSSV_ROOT/src/fohssv_sim/config/fastdds_localhost.xml"
  export _FOHSSV_SET_PROFILE="$FASTDDS_DEFAULT_PROFILES_FILE"
  _fohssv_default=SUBNET
else
  unset _FOHSSV_SET_PROFILE
  _fohssv_default=LOCALHOST
fi
if [ -z "$_fohssv_range" ]; then
  export ROS_AUTOMATIC_DISCOVERY_RANGE="$_fohssv_default"
  export _FOHSSV_SET_RANGE="$_fohssv_default"
else
  export ROS_AUTOMATIC_DISCOVERY_RANGE="$_fohssv_range"
  if [ "$_fohssv_default" = SUBNET ] && [ "$_fohssv_range" = LOCALHOST ]; then
    echo "fohssv: keeping your ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; with the loopback" \
         "Fast DDS profile your own rclpy processes then bind 0.0.0.0 and are discovered" \
         "late (the fohssv nodes use SUBNET over loopback): unset it and source env.sh" \
         "again for SUBNET (README.md, Discovery)" >&2
  elif [ "$_fohssv_default" = LOCALHOST ] && [ "$_fohssv_range" = SUBNET ] \
       && [ "${_FOHSSV_SET_RANGE:-}" = SUBNET ]; then
    echo "fohssv: keeping ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET (an earlier source of env.sh" \
         "set it, or you did) without the loopback profile: discovery reaches other hosts;" \
         "export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST to stay on this one" >&2
  fi
  [ "$_fohssv_range" = "${_FOHSSV_SET_RANGE:-}" ] || unset _FOHSSV_SET_RANGE   # yours
fi
unset _fohssv_range _fohssv_profile _fohssv_default

if [ -f "$FOHSSV_ROOT/ros2_ws/install/setup.sh" ]; then
  # colcon's setup scripts fail under `set -u`: relax it while sourcing.
  case $- in *u*) _fohssv_u=1; set +u ;; *) _fohssv_u= ;; esac
  COLCON_CURRENT_PREFIX="$FOHSSV_ROOT/ros2_ws/install" . "$FOHSSV_ROOT/ros2_ws/install/setup.sh"
  [ -n "$_fohssv_u" ] && set -u
  unset _fohssv_u
fi
