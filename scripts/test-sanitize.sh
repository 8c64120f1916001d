#!/usr/bin/env bash
# Builds the C++ unit tests with AddressSanitizer and UndefinedBehaviorSanitizer in
# build/sanitize (CMake option TESSERA_SANITIZE) and runs them. Every finding aborts the
# test process (-fno-sanitize-recover=all, halt_on_error=1), so any finding fails this
# script. Called by scripts/test.sh; re-runs rebuild only what changed.
#
# Embree and TBB are the system's uninstrumented libraries; ASan still checks every access
# our code makes, including to buffers it shares with them. No suppressions are needed
# (none is allowed unless the report is provably inside Embree or TBB; add them to
# scripts/sanitize.supp with a comment saying why).
#
# Left out under the sanitizers: the long statistical renders listed in
# scripts/cpp-long-tests.txt (each line names the shorter tests that run the same code
# here). They take 2.5 min or more each under ASan and run in the plain build of
# scripts/test.sh. The rest runs in two shards at once (GoogleTest's sharding), one per core.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
source "$ROOT/scripts/ccache-env.sh"
BUILD=$ROOT/build/sanitize
SANITIZERS=address,undefined
LONG_TESTS=$(sed -e 's/#.*//' -e 's/[[:space:]]//g' "$ROOT/scripts/cpp-long-tests.txt" | grep -v '^$' | paste -sd:)

start=$(date +%s)
echo "[sanitize] building the C++ tests with -fsanitize=$SANITIZERS ($BUILD)"
cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTESSERA_BUILD_TESTS=ON \
      -DTESSERA_SANITIZE="$SANITIZERS" > "$BUILD.configure.log" 2>&1 \
  || { cat "$BUILD.configure.log"; echo "[sanitize] configure failed"; exit 1; }
cmake --build "$BUILD" --target tessera_core_tests -j "$(nproc)" || { echo "[sanitize] build failed"; exit 1; }
built=$(date +%s)

export ASAN_OPTIONS="halt_on_error=1:abort_on_error=1:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1:suppressions=$ROOT/scripts/sanitize.supp"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:suppressions=$ROOT/scripts/sanitize.supp"
export LSAN_OPTIONS="suppressions=$ROOT/scripts/sanitize.supp"
# Canaries: the same flags must catch a use after free (ASan) and a signed overflow
# (UBSan), or this run could not fail.
canary() {
  printf '%s\n' "$2" | c++ -x c++ -O1 -fsanitize=$SANITIZERS -fno-sanitize-recover=all - -o "$BUILD/canary-$1" \
    && ! ("$BUILD/canary-$1" 7 > "$BUILD/canary-$1.log" 2>&1) 2>/dev/null && grep -q "$3" "$BUILD/canary-$1.log"
}
canary asan 'int main(int argc, char**) { int* p = new int[argc]; delete[] p; return ((volatile int*)p)[0]; }' \
  heap-use-after-free \
  && canary ubsan '#include <climits>
int main(int argc, char**) { int x = INT_MAX - 1; x += argc * 2; return x == 0; }' "signed integer overflow" \
  || { echo "[sanitize] the sanitizers did not catch the canary bugs: this run could not fail"; exit 1; }

SHARDS=2
pids=()
for i in $(seq 0 $((SHARDS - 1))); do
  GTEST_TOTAL_SHARDS=$SHARDS GTEST_SHARD_INDEX=$i \
    "$BUILD/renderer/tessera_core_tests" --gtest_brief=1 --gtest_filter="-$LONG_TESTS" \
    > "$BUILD/shard-$i.log" 2>&1 &
  pids+=($!)
done
rc=0
for i in "${!pids[@]}"; do
  wait "${pids[$i]}" || rc=$?
  cat "$BUILD/shard-$i.log"
done
echo "[sanitize] build $((built - start)) s, tests $(($(date +%s) - built)) s"
if [ $rc -ne 0 ]; then echo "[sanitize] FAILED (exit $rc): see the sanitizer report above"; fi
exit $rc
