# Sourced by setup.sh, test.sh and test-sanitize.sh: every C++ build of the
# suite (the core, its tests, the ASan + UBSan build, the Lambert-only core and the wheel)
# goes through ccache when it is installed (setup.sh installs it). Paths are hashed
# relative to the checkout (CCACHE_BASEDIR) and the build folder is not hashed
# (CCACHE_NOHASHDIR), so a fresh clone in another folder reuses the objects an earlier
# build compiled from the same sources: on 2 cores the builds are most of the suite's
# first minutes. TESSERA_NO_CCACHE=1 turns it off (a cold build, as on a new machine).
if [ -z "${TESSERA_NO_CCACHE:-}" ] && command -v ccache > /dev/null 2>&1; then
  export CMAKE_CXX_COMPILER_LAUNCHER=ccache CMAKE_C_COMPILER_LAUNCHER=ccache
  export CCACHE_BASEDIR="$ROOT" CCACHE_NOHASHDIR=true
  # ASan, plain, Lambert-only and wheel builds of the core: about 0.4 GB together.
  export CCACHE_MAXSIZE=${CCACHE_MAXSIZE:-5G}
fi
