#!/usr/bin/env bash
# Sets everything up (scripts/setup.sh), then runs the whole test suite: the C++ unit
# tests (GoogleTest through ctest, then again built with ASan + UBSan by
# scripts/test-sanitize.sh) and the Python tests (pytest; they start their own
# redis-server, API and worker processes), then `tessera refs check examples/refs` (the
# examples against their committed references). Exits non-zero if any test fails.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
source "$ROOT/scripts/ccache-env.sh"
bash "$ROOT/scripts/setup.sh" || { echo "[test] set-up failed"; exit 1; }
VENV=${TESSERA_VENV:-$ROOT/.venv}

build_dir=$(ls -td "$ROOT"/build/*/ 2>/dev/null | grep -v '/sanitize/$' | head -n 1)
status=0
if [ -z "$build_dir" ] || [ ! -f "$build_dir/CTestTestfile.cmake" ]; then
  echo "[test] no C++ build directory with tests under build/"; status=1
else
  echo "[test] C++ tests ($build_dir)"
  # One test process per core: most are single-threaded, and the long renders' threads
  # share the cores with them.
  ctest --test-dir "$build_dir" --output-on-failure -j "$(nproc)" || status=1
fi

echo "[test] C++ tests under ASan + UBSan"
bash "$ROOT/scripts/test-sanitize.sh" || status=1

echo "[test] Python tests"
cd "$ROOT"
# Two workers (pytest-xdist), a test module per worker at a time: most farm tests wait on
# processes they started, and a module's fixtures (its renders, its farm) stay its own.
"$VENV/bin/python" -m pytest -n "$(nproc)" --dist loadfile "$@"
rc=$?
# pytest exits 5 when it collected nothing: that is a failure here, not a pass.
[ $rc -eq 0 ] || status=1

# Tessera guards its own look with its own tool: the examples against their committed
# reference sets (docs/accuracy.md); the HTML report and JUnit file stay in build/.
echo "[test] render checks of examples/ against examples/refs"
"$VENV/bin/tessera" refs check "$ROOT/examples/refs" --report "$ROOT/build/refs-check" \
  --junit "$ROOT/build/refs-check/junit.xml" || status=1

if [ $status -eq 0 ]; then echo "[test] all passed"; else echo "[test] FAILED"; fi
exit $status
