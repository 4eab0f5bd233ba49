#!/usr/bin/env bash
# Create or reuse the virtual environment, install gltrack and, when missing, the system GL libraries.
# Sourced by scripts/demo.sh and scripts/test.sh; sets $PY to the environment's python.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${GLTRACK_VENV:-$ROOT/.venv}"
GL_PACKAGES="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libgl1"

have_gl_libs() {
    ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' &&
    ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0' &&
    ldconfig -p 2>/dev/null | grep -q 'libgbm.so.1' &&
    ldconfig -p 2>/dev/null | grep -q 'libGL.so.1'
}

if ! have_gl_libs; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
        echo "gltrack setup: installing system GL libraries: $GL_PACKAGES"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $GL_PACKAGES >/dev/null
    else
        echo "gltrack setup: the Mesa EGL libraries are missing. Install them, e.g.:" >&2
        echo "    sudo apt-get install $GL_PACKAGES" >&2
        exit 1
    fi
fi

PYTHON="${PYTHON:-python3}"
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
    echo "gltrack setup: Python >= 3.10 is required ($PYTHON is $("$PYTHON" --version 2>&1))" >&2
    exit 1
fi
if [ ! -x "$VENV/bin/python" ]; then
    echo "gltrack setup: creating virtual environment $VENV"
    "$PYTHON" -m venv "$VENV"
fi
PY="$VENV/bin/python"
# Reinstall only when pyproject.toml changed since the last install.
STAMP="$VENV/.gltrack-installed"
if [ ! -f "$STAMP" ] || [ "$ROOT/pyproject.toml" -nt "$STAMP" ]; then
    echo "gltrack setup: installing gltrack and its dependencies into $VENV"
    LOG="$VENV/pip-install.log"
    if ! { "$PY" -m pip install --upgrade pip && "$PY" -m pip install -e "$ROOT[test]"; } >"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        echo "gltrack setup: pip install failed (full log: $LOG)" >&2
        exit 1
    fi
    touch "$STAMP"
fi
# MediaPipe's pose landmark model (keypoints, gltrack/observe/keypoints.py): copied once out of
# the mediapipe wheel on PyPI. Optional: without it ingest writes no keypoints.
if [ ! -f "$VENV/share/gltrack/models/pose_landmark_full.tflite" ]; then
    "$PY" "$ROOT/scripts/fetch_pose_model.py" "$VENV/share/gltrack/models" ||
        echo "gltrack setup: the pose landmark model is not installed; datasets get no keypoints" >&2
fi
export PY
