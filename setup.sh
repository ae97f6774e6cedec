#!/usr/bin/env bash
# physdyn_ros setup: a fresh Debian 12 machine with Python 3.11 -> a ready environment in .venv/.
#   apt packages, the virtual environment, pinned Python packages, the ROS interface build, the package.
# Re-running it on a ready machine only rebuilds what changed (a few seconds).
# Every failing step stops the script with "setup: FAILED: <step>" and the end of that step's log.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$ROOT/.venv"
PY="${PYTHON:-python3.11}"
BUILD="$ROOT/build/setup"
LOGDIR="$BUILD/logs"
mkdir -p "$LOGDIR"

say() { printf 'setup: %s\n' "$*"; }
# step NAME CMD... : run CMD with its output in a log; on failure name the step and show the log's end.
step() {
  local name="$1"; shift
  local log="$LOGDIR/$(echo "$name" | tr -c 'a-zA-Z0-9' '_').log"
  local t0=$SECONDS
  if "$@" >"$log" 2>&1; then
    say "ok   $name ($((SECONDS - t0)) s)"
  else
    say "FAILED: $name (exit $?); last lines of $log:"
    tail -n 25 "$log" | sed 's/^/  | /'
    say "FAILED: $name"
    exit 1
  fi
}

# 1. System packages: open3d needs libusb and libGL; the interface build needs cmake and a C/C++ compiler.
APT_PKGS=(libusb-1.0-0 libgl1 libgomp1 cmake g++ make python3-venv)
missing=()
for p in "${APT_PKGS[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if ((${#missing[@]})); then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  step "apt-get update" $SUDO apt-get update
  step "apt-get install ${missing[*]}" env DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "${missing[@]}"
fi

command -v "$PY" >/dev/null 2>&1 || PY=python3
"$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' 2>/dev/null \
  || { say "FAILED: Python 3.11 is required (found $("$PY" --version 2>&1)); set PYTHON=/path/to/python3.11"; exit 1; }

# 2. The virtual environment and the pinned packages (skipped when requirements.txt is unchanged).
[ -x "$VENV/bin/python" ] || step "create .venv" "$PY" -m venv "$VENV"
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)
stamp="$VENV/.physdyn-requirements.sha256"
want="$(sha256sum "$ROOT/requirements.txt" | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  step "pip install -r requirements.txt" "${PIP[@]}" install -r "$ROOT/requirements.txt"
  echo "$want" >"$stamp"
fi

# 3. The ROS wheels' exported CMake targets name the include folders of the machine that built them
#    (/opt/python/cp311-cp311/...); point them at this interpreter's and numpy's include folders.
fix_exports() {
  local pyinc npinc
  pyinc="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
  npinc="$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')"
  local files
  files="$(grep -rlF "/opt/python/cp311-cp311" "$VENV/share" --include='*.cmake' || true)"
  for f in $files; do
    sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$npinc#g" \
           -e "s#/opt/python/cp311-cp311/include/python3.11#$pyinc#g" "$f"
  done
  echo "patched $(echo "$files" | grep -c . || true) files"
}
step "fix ROS wheel include paths" fix_exports

# 4. The package manifest must parse (ament's own parser) before anything is built.
step "validate package.xml" "$VENV/bin/python" -c "
from catkin_pkg.package import parse_package
p = parse_package('$ROOT/package.xml')
assert p.name == 'physdyn_ros', 'package name must be physdyn_ros, got %r' % p.name
print(p.name, p.version)"

# 5. Generate and build the interfaces (rosidl) and install them into the venv prefix.
export CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV"
step "configure interfaces (cmake)" cmake -S "$ROOT" -B "$BUILD/cmake" \
  -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
  -DPHYSDYN_INSTALL_PYTHON=OFF -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release
step "build interfaces" cmake --build "$BUILD/cmake" -j "$(nproc)"
step "install interfaces" cmake --install "$BUILD/cmake"
# rosidl also writes an egg-info named physdyn_ros; pip owns that name (and would uninstall the generated
# modules with it on a re-run), so keep only pip's metadata.
# Its generated physdyn_ros/__init__.py (empty) goes too: without it that folder is only a namespace
# portion, so the source tree's physdyn_ros (editable install below) is the package, and its __init__.py
# extends __path__ to the generated msg/ and srv/ modules.
SITE="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
rm -rf "$SITE"/physdyn_ros-*.egg-info "$SITE/physdyn_ros/__init__.py"

# 6. The Python package (editable: edits in the source tree take effect at once) and its entry points.
step "pip install -e physdyn_ros" "${PIP[@]}" install --no-deps --no-build-isolation \
  --config-settings editable_mode=compat -e "$ROOT"

# 7. Everything imports from the venv with no sourcing.
step "check imports" "$VENV/bin/python" -c "
import rclpy, open3d, pybullet, torch
from physdyn_ros.msg import ObjectState, PredictedTrajectory, ShapeFeature
from physdyn_ros.srv import PlanPush, PredictTrajectory, PushObject, SpawnObject
from physdyn_ros.action import PushToGoal
import physdyn_ros.cli
print('torch', torch.__version__)"
step "check physdyn command" "$VENV/bin/physdyn" --help
say "ready: $VENV (run the tests with: .venv/bin/python -m pytest -q test)"
