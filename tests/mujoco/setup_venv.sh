#!/usr/bin/env bash
# Create (or refresh) the venv that records the third-party test set: MuJoCo (engine and
# offscreen renderer through Mesa's EGL), rosbags (the rosbag2 writer) and Pillow (JPEG colour
# for the realsense layout). Usage: setup_venv.sh VENV
set -euo pipefail
VENV=$1
# Mesa's software EGL and OpenGL for MuJoCo's offscreen renderer.
if ! ldconfig -p | grep -q 'libEGL_mesa.so' || ! ldconfig -p | grep -q 'libGL.so.1'; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri >/dev/null
fi
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install -q 'mujoco==4.0.0' 'rosbags==0.11.9' 'pillow==12.0.0' numpy
MUJOCO_GL=egl "$VENV/bin/python" -c 'import mujoco; m = mujoco.MjModel.from_xml_string("<mujoco/>"); mujoco.Renderer(m, 8, 8).close()'
