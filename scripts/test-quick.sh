#!/usr/bin/env bash
# The quick tier, while you work (after scripts/setup.sh): the C++ unit tests without the
# long statistical renders (scripts/cpp-long-tests.txt) and `pytest -m "not slow"` (no real
# farms, bench, fuzzing or long renders: tests/conftest.py SLOW_MODULES). The whole suite
# is scripts/test.sh. Extra arguments go to pytest.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${TESSERA_VENV:-$ROOT/.venv}
tests=$(ls -t "$ROOT"/build/*/renderer/tessera_core_tests 2>/dev/null | grep -v '/sanitize/' | head -n 1)
[ -n "$tests" ] || { echo "[quick] no C++ test binary under build/: run scripts/setup.sh first"; exit 1; }
LONG_TESTS=$(sed -e 's/#.*//' -e 's/[[:space:]]//g' "$ROOT/scripts/cpp-long-tests.txt" | grep -v '^$' | paste -sd:)
status=0
echo "[quick] C++ unit tests without the long renders ($tests)"
# Two shards (GoogleTest's sharding) run beside pytest: most C++ tests are single-threaded and
# pytest's workers spend much of their time waiting on the processes they start.
SHARDS=$(nproc)
log=$(mktemp -d)
pids=()
for i in $(seq 0 $((SHARDS - 1))); do
  GTEST_TOTAL_SHARDS=$SHARDS GTEST_SHARD_INDEX=$i "$tests" --gtest_brief=1 --gtest_filter="-$LONG_TESTS" \
    > "$log/shard-$i.log" 2>&1 &
  pids+=($!)
done
echo "[quick] Python tests, not slow"
# Both cores unless the arguments choose (-n N, -p no:xdist).
case " $* " in *" -n"*|*"--numprocesses"*|*"no:xdist"*) workers=() ;; *) workers=(-n "$(nproc)") ;; esac
cd "$ROOT" && "$VENV/bin/python" -m pytest -m "not slow" "${workers[@]}" "$@" || status=1
echo "[quick] C++ unit tests: the shards' output"
for i in "${!pids[@]}"; do
  wait "${pids[$i]}" || status=1
  cat "$log/shard-$i.log"
done
rm -rf "$log"
if [ $status -eq 0 ]; then echo "[quick] all passed"; else echo "[quick] FAILED"; fi
exit $status
