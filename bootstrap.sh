#!/usr/bin/env bash
# One entry point for a fresh machine: sets up everything affordmap needs, then runs one job.
#
#   bash bootstrap.sh demo [ARGS]   sets up, then maps the built-in example room (afford demo)
#   bash bootstrap.sh test [ARGS]   sets up, then runs ruff, the import contracts and the whole test suite (CI)
#
# Needs only Python >= 3.11. Missing system libraries (open3d, afford synth's ray caster in the learn extra,
# needs libGL, libEGL and libusb) are installed with apt-get when running as root; otherwise the script stops
# and prints the line to run. As root, `test` also installs protoc, the protobuf C++ headers, g++ and
# pkg-config (the C++ client test, which then must run: it fails rather than skips).
set -euo pipefail
cd "$(dirname "$0")"

job=${1:-}
case "$job" in
  demo|test) shift ;;
  *) echo "usage: bash bootstrap.sh {demo|test} [args...]" >&2; exit 2 ;;
esac

find_python() {
  for candidate in "${PYTHON:-}" python3.11 python3.12 python3.13 python3; do
    [ -n "$candidate" ] || continue
    if command -v "$candidate" >/dev/null 2>&1 &&
       "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
      echo "$candidate"; return 0
    fi
  done
  echo "error: affordmap needs Python >= 3.11 (set PYTHON=/path/to/python3.11)" >&2
  return 1
}
PY=$(find_python)

# System packages: shared libraries open3d loads (the learn extra's, which .[all] installs), and venv support.
missing=()
have_lib() { { /sbin/ldconfig -p 2>/dev/null || ldconfig -p 2>/dev/null; } | grep -q "$1"; }
have_lib 'libGL.so.1 '        || missing+=(libgl1)
have_lib 'libEGL.so.1 '       || missing+=(libegl1)
have_lib 'libusb-1.0.so.0 '   || missing+=(libusb-1.0-0)
have_lib 'libgomp.so.1 '      || missing+=(libgomp1)
if [ ! -x .venv/bin/python ] && ! "$PY" -c 'import ensurepip, venv' 2>/dev/null; then
  missing+=("python3-venv")
fi
# For the tests only, and only where apt-get runs as root: protoc, the protobuf C++ headers, g++ and
# pkg-config, with which tests/test_cpp_client.py builds a C++ client from schemas/ (AFFORD_TEST_CPP=required
# makes a missing piece a failure there, never a quiet skip), and Xvfb with a software Vulkan driver, with
# which tests/test_screenshots.py runs the Rerun viewer (elsewhere those tests skip and say why).
if [ "$job" = test ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  command -v protoc >/dev/null 2>&1                  || missing+=(protobuf-compiler)
  [ -e /usr/include/google/protobuf/message.h ]      || missing+=(libprotobuf-dev)
  command -v g++ >/dev/null 2>&1                     || missing+=(g++)
  command -v pkg-config >/dev/null 2>&1              || missing+=(pkg-config)
  export AFFORD_TEST_CPP=required
  # the Rerun viewer, headless, for tests/test_screenshots.py (it skips without them)
  command -v Xvfb >/dev/null 2>&1                    || missing+=(xvfb)
  have_lib 'libvulkan.so.1 '                         || missing+=(libvulkan1 mesa-vulkan-drivers)
  have_lib 'libxkbcommon-x11.so.0 '                  || missing+=(libxkbcommon-x11-0)
fi
if [ ${#missing[@]} -gt 0 ]; then
  line="apt-get update && apt-get install -y --no-install-recommends ${missing[*]}"
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing system packages: ${missing[*]}" >&2
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "error: missing system packages: ${missing[*]}" >&2
    echo "run as root:  sudo sh -c '$line'" >&2
    exit 1
  fi
fi

# Virtual environment, reinstalled only when the package's dependencies change.
if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv with $PY" >&2
  "$PY" -m venv .venv
fi
# the tests also install Ray ([cluster]), so tests/test_cluster.py runs a head and a worker node in CI, and
# a .venv set up for the tests has everything the demo needs, so `demo` after `test` installs nothing;
stamp_of() { (cat pyproject.toml; echo "$1") | sha256sum | cut -d' ' -f1; }
# and real ROS 2's rclpy ([ros2-test], where its wheels exist for this Python), which tests/test_rclpy.py
# checks the wire against
extras="all,test"
test_extras="all,cluster,test,ros2-test"
[ "$job" = test ] && extras=$test_extras
stamp=$(stamp_of "$extras")
installed=$(cat .venv/.afford-stamp 2>/dev/null || true)
if [ "$installed" != "$stamp" ] && [ "$installed" != "$(stamp_of "$test_extras")" ]; then
  echo "bootstrap: installing affordmap and its dependencies into .venv (a minute or two)" >&2
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -e ".[$extras]"
  echo "$stamp" > .venv/.afford-stamp
fi

case "$job" in
  demo) exec .venv/bin/afford demo "$@" ;;
  test)
    # Static checks first (seconds): style, then the layers of README's "Layout" (pyproject.toml's contracts).
    .venv/bin/ruff check --quiet .
    .venv/bin/ruff format --check --quiet .
    .venv/bin/lint-imports --no-cache | tail -n +13
    # One worker per core, a test module to a worker (module fixtures, such as a stack of services, are
    # made once); `-n 0` after `test` runs everything in this process.
    exec .venv/bin/python -m pytest -n 2 --dist loadfile "$@" ;;
esac
