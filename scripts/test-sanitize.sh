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
# Left out under the sanitizers, to keep CI time small: the long statistical tests
# (BsdfChiSquare.SampleFollowsPdfForEveryBSDF, BsdfFurnace.WhiteMaterialsReflectAtMostOne:
# about 50 s plain, 2.5 min under ASan; the energy furnace over every roughness, ior and
# angle, the emitting-box furnace and the two path/light/bdpt agreement renders: 15-24 s
# each under ASan). They run the BSDF, sampling and integrator code that the other tests
# (reciprocity, robustness at extremes, per-lobe chi-square, the small furnaces and
# agreement scenes) run under the sanitizers too, only with many more samples; the plain
# ctest run still runs them (so does the shaped area light's path/light/bdpt agreement,
# whose API-level sibling runs here). Likewise the five motion-blur renders (the sliding
# emitter's, the sliding camera's and the deforming emitters' ramps, the moving lights'
# irradiance and the blurred shadow, 3-27 s plain): Motion.IntegratorsWithAScenePass...
# runs the moving-instance code, Motion.ADeformingEmitterIsSampledByItsAreaAtTheInstant the
# deforming-mesh code and Motion.MovingLightsAreSeenAndSampledWhereTheyAreAtTheInstant the
# moving-light code under the sanitizers.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
BUILD=$ROOT/build/sanitize
SANITIZERS=address,undefined
SLOW_TESTS="BsdfChiSquare.SampleFollowsPdfForEveryBSDF:BsdfFurnace.WhiteMaterialsReflectAtMostOne"
SLOW_TESTS+=":PreviewSurfaceEnergy.WhiteFurnaceIsOneForEveryRoughnessIorAndAngle"
SLOW_TESTS+=":Materials.PreviewSurfaceFurnaceIsLeOverOneMinusAlbedo"
SLOW_TESTS+=":Integrators.PathLightAndBidirectionalAgreeForEveryLightKind:Camera.LensPathLightAndBidirectionalAgree"
SLOW_TESTS+=":Motion.SlidingEmitterGivesTheClosedFormRampForEveryIntegratorThatSeesEmitters:Motion.BlurredShadowEqualsTheTimeAverageOfStaticShadows:Motion.ACameraSlidingPastAStillQuadSeesTheSameRampAsTheQuadSlidingPastIt"
SLOW_TESTS+=":Motion.DeformingEmittersGiveTheClosedFormCoverageForEveryIntegratorThatSeesEmitters"
SLOW_TESTS+=":Motion.MovingPointSphereAndDistantLightsGiveTheClosedFormIrradiance"
# Its 2 x 10^8 photon paths take minutes under the sanitizers; the same tracing, slicing and
# grids run there in Motion.TracedPhotons... and the PhotonDirect tests.
SLOW_TESTS+=":Motion.PhotonDensityOnAMovingReceiverIsTheTimeAverageOfStaticOnes"
SLOW_TESTS+=":AreaLightShaping.PathLightAndBidirectionalAgreeOnTheShapedPool"

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

"$BUILD/renderer/tessera_core_tests" --gtest_brief=1 --gtest_filter="-$SLOW_TESTS"
rc=$?
echo "[sanitize] build $((built - start)) s, tests $(($(date +%s) - built)) s"
if [ $rc -ne 0 ]; then echo "[sanitize] FAILED (exit $rc): see the sanitizer report above"; fi
exit $rc
