# Sourced by scripts/test and scripts/demo: installs what a fresh Debian bookworm lacks (as
# root, with apt-get), makes the project's own Python environment (.venv, from Debian's
# python3-venv: pip may not touch the system Python), and builds into build/.
# Afterwards: $PY is the venv's python, $BUILD the build dir, $MAVBOND the daemon.

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
BUILD=${MAVBOND_BUILD_DIR:-$ROOT/build}
VENV=${MAVBOND_VENV:-$ROOT/.venv}
DEB_PACKAGES=(g++ meson ninja-build pkgconf libyaml-cpp-dev libboost-dev libgtest-dev libgmock-dev
              python3 python3-venv ca-certificates procps iproute2
              clang-14 clang libclang-rt-14-dev)   # scripts/fuzz: libFuzzer
# A script that needs more sets TEST_DEB_PACKAGES before sourcing this file (scripts/test).
DEB_PACKAGES+=(${TEST_DEB_PACKAGES[@]+"${TEST_DEB_PACKAGES[@]}"})
# One line: scripts/package reads it. matplotlib draws scripts/compare's plots; prometheus-client
# parses /metrics in tests/integration/test_metrics.py; mavsdk (a wheel with MAVSDK's C++
# library) and MAVProxy are the independent MAVLink stacks of tests/peers.
PY_PACKAGES=(pymavlink==2.4.50 mmh3==5.1.0 pytest==8.3.4 matplotlib==3.10.8 prometheus-client==0.26.0 mavsdk==4.1.0 MAVProxy==1.8.75)

say() { printf '==> %s [%s]\n' "$*" "$(date +%T)" >&2; }

install_debian_packages() {
    local missing=()
    for p in "${DEB_PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ]; then
        say "missing Debian packages: ${missing[*]} (run as root, or install them first)"
        exit 1
    fi
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q >&2
    apt-get install -y -q --no-install-recommends "${missing[@]}" >&2
}

make_venv() {
    local stamp="$VENV/.mavbond-packages"
    if [ -x "$VENV/bin/python" ] && [ "$(cat "$stamp" 2>/dev/null)" = "${PY_PACKAGES[*]}" ]; then
        return 0
    fi
    say "creating $VENV with ${PY_PACKAGES[*]}"
    # Debian's own python3, whatever else is on PATH: the venv must work on a stock system.
    /usr/bin/python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q --disable-pip-version-check "${PY_PACKAGES[@]}" >&2
    echo "${PY_PACKAGES[*]}" > "$stamp"
}

build_project() {
    if [ ! -f "$BUILD/build.ninja" ]; then
        say "configuring $BUILD"
        meson setup "$BUILD" "$ROOT" -Dpython="$VENV/bin/python" >&2
    fi
    say "building"
    ninja -C "$BUILD" >&2
}

install_debian_packages
make_venv
# scripts/fuzz builds only its own tree (MAVBOND_SETUP_NO_BUILD=1).
[ "${MAVBOND_SETUP_NO_BUILD:-0}" = 1 ] || build_project
PY="$VENV/bin/python"
MAVBOND="$BUILD/src/mavbond"
export MAVBOND_BIN="$MAVBOND"
