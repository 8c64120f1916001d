#!/usr/bin/env bash
# Installs everything Tessera needs on a fresh Debian 12 machine and builds it.
# Idempotent: a second run finds the packages present and rebuilds incrementally.
#   TESSERA_VENV   Python virtual environment to use/create (default: .venv in the repo)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${TESSERA_VENV:-$ROOT/.venv}
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"

APT_PACKAGES=(
  build-essential cmake ninja-build pkg-config python3-venv
  python3-dev  # Python.h: the core is a Python extension (nanobind); not in a minimal Debian 12
  libembree-dev libtbb-dev libopenimageio-dev openimageio-tools libopenexr-dev
  libosd-dev  # OpenSubdiv: subdivision surfaces refined at translation time
  libopenvdb-dev libboost-dev  # OpenVDB (its headers need Boost): UsdVol.Volume fields (.vdb) read at translation time
  python3-openvdb  # makes the tests' small .vdb files (with the system Python's numpy)
  openexr  # exrheader/exrinfo: tests check that OpenEXR's own tools read every EXR we write
  libgtest-dev redis-server iproute2
  ccache  # compiler cache: a re-run or a fresh clone rebuilds only what changed (scripts/ccache-env.sh)
  libllvm19  # Mitsuba's llvm_ad_rgb variant, the second peer in `tessera bench`
  chromium chromium-driver  # the monitor page's browser tests (selenium drives them)
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "[setup] installing Debian packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  # The image deletes .deb files after any update; a concurrent update can break an
  # install half-way, so repair and retry once.
  if ! $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
    $SUDO apt-get --fix-broken install -y -qq
    $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
  fi
fi

# shellcheck source=scripts/ccache-env.sh
source "$ROOT/scripts/ccache-env.sh"

PY=${PYTHON:-python3}
if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating virtual environment $VENV"
  "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"
"$VPY" -m pip install -q --upgrade pip
# Build requirements are installed up front so the build can run without isolation and
# reuse its build directory (build/<wheel tag>): re-runs compile only what changed.
"$VPY" -m pip install -q "scikit-build-core>=0.10" "nanobind>=2.0"
echo "[setup] building and installing Tessera (C++ core, Python packages)"
# The C++ unit tests are built beside the core here (ctest in build/<wheel tag>), never
# into a wheel (`pip wheel .`, docs: README "Using it elsewhere").
"$VPY" -m pip install -q --no-build-isolation --config-settings=cmake.define.TESSERA_BUILD_TESTS=ON \
  -e "$ROOT[test]"
echo "[setup] ready: $VENV/bin/tessera"
