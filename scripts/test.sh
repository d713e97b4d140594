#!/usr/bin/env bash
# Installs dependencies, fetches the real meshes, configures, builds and runs the tests.
# Exits non-zero on any failure. BUILD_DIR (default build/) and JOBS may be set.
#
#   scripts/test.sh                      Release build (gcc), every test
#   scripts/test.sh --sanitize address   clang + AddressSanitizer + UBSan in build-asan/: the unit,
#                                        race, service and CLI-inspect tests (brenierd itself
#                                        sanitized), and the fuzz targets built and run briefly
#   scripts/test.sh --sanitize thread    clang + ThreadSanitizer in build-tsan/: the same tests
#                                        (both leave the seven longest numeric solves to Release)
#   scripts/test.sh --sanitize all       both sanitizer runs (CI runs this after the plain one)
#
# Why these suites: the real-mesh suites and the CLI map and distance runs are minutes of
# numerics in Release and would take hours sanitized; what they exercise under a sanitizer
# (readers, the transport, the cells, OpenMP loops) the unit tests and fuzzers cover on small
# inputs. Everything that has threads or sockets (the server, its races) runs under both.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
JOBS="${JOBS:-$(nproc)}"
SANITIZE=""
while (($#)); do
  case "$1" in
    --sanitize) SANITIZE="${2:?--sanitize needs address, thread or all}"; shift 2 ;;
    *) echo "test.sh: unknown argument '$1' (--sanitize address|thread|all)" >&2; exit 2 ;;
  esac
done

bash "$ROOT/scripts/install-deps.sh"
bash "$ROOT/scripts/fetch-data.sh"

if [[ -z "$SANITIZE" ]]; then
  BUILD_DIR="${BUILD_DIR:-$ROOT/build}"
  cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
  cmake --build "$BUILD_DIR" -j "$JOBS"
  cd "$BUILD_DIR"
  exec ctest --output-on-failure -j "$JOBS" --timeout 1200
fi

SUPP="$ROOT/tests/sanitizers"

sanitized() {  # $1: address or thread
  local kind=$1 dir
  if [[ $kind == address ]]; then dir="$ROOT/build-asan"; else dir="$ROOT/build-tsan"; fi
  local extra=()
  [[ $kind == address ]] && extra=(-DBRENIER_BUILD_FUZZ=ON)
  echo "== sanitizer build: $kind in $dir"
  CC=clang CXX=clang++ cmake -S "$ROOT" -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DBRENIER_SANITIZE="$kind" -DBRENIER_BUILD_BENCH=OFF "${extra[@]}" >/dev/null
  cmake --build "$dir" -j "$JOBS"
  (
    cd "$dir"
    export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
    export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=1"
    export LSAN_OPTIONS="suppressions=$SUPP/lsan.supp:print_suppressions=0"
    # OpenMP's own synchronization is invisible to TSan unless libomp's Archer tool reports
    # it; accesses inside uninstrumented libraries (libomp, gRPC) are not checked.
    export TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:ignore_noninstrumented_modules=1:suppressions=$SUPP/tsan.supp"
    export OMP_TOOL_LIBRARIES=/usr/lib/llvm-14/lib/libarcher.so
    # A sanitized build registers no real-mesh suite (tests/CMakeLists.txt). Of the tests it
    # has, the longest numeric solves are left to the Release run: each is 1-5 minutes under
    # ASan (about half the sanitized numerics' time in CI) for code that shorter sanitized
    # tests run on small inputs: the multilevel starts (Omt.TheMultilevelStartIsTaken...,
    # Omt.AStalledCoarseToFine...), the stall watch (Omt.AStallWatchFires...), the surface
    # transport on two threads (SurfaceOmt.TheDampedStepsAreTheSameOnOneThreadAsOnTwo) and the
    # sphere distances (Distance.OnTheSphere..., Distance.SphereShapesWithMergedSites...); the
    # stalled sphere transports' lower caps run through the same solves.
    local long_numerics='^(Distance\.ASpherePairWithOneCrowdedDensityIsTheTransportFromTheOther'
    long_numerics+='|Distance\.ASphereTransportThatStallsIsSolvedAgainAtALowerCapAndSaysSo'
    long_numerics+='|Distance\.ASphereDensityFarAboveItsMeanIsSolvedAtAHundredTimesTheMean'
    long_numerics+='|Distance\.ASpherePairConvergingAtNoCapReportsBothDirectionsDuals'
    long_numerics+='|Distance\.ASurfaceTransportThatCreepsStopsAsStalledAfterItsWindow'
    long_numerics+='|SurfaceOmt\.TheMultilevelSolveReachesThePlainSolvesTransport'
    long_numerics+='|Omt\.TheMultilevelSolveReachesThePlainSolvesTransport'
    long_numerics+='|Omt\.ThePlanarStallWindowStopsNoSolveThatConvergesAndSaysWhenItStops'
    long_numerics+='|Omt\.TheAlternativeStartReplacesTheCoarseToFineOneOnlyWhereItsDualIsHigher)$'
    ctest --output-on-failure -j "$JOBS" --timeout 1500 -E "$long_numerics"
    if [[ $kind == address ]]; then bash "$ROOT/scripts/fuzz.sh" "$dir" --runs 20000; fi
  )
}

case "$SANITIZE" in
  address|thread) sanitized "$SANITIZE" ;;
  all) sanitized address; sanitized thread ;;
  *) echo "test.sh: --sanitize takes address, thread or all, not '$SANITIZE'" >&2; exit 2 ;;
esac
