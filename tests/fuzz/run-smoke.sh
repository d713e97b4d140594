#!/usr/bin/env bash
# Short fuzzing smoke run of every reader (not part of ctest): builds the libFuzzer targets
# with clang, AddressSanitizer and UBSan in build-fuzz/, seeds each with the fixtures of its
# format, and runs each for SECONDS (default 30). Exits non-zero on the first crash.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
SECONDS_EACH="${1:-30}"
BUILD="$ROOT/build-fuzz"
command -v clang++ >/dev/null || { echo "run-smoke: clang++ is needed (apt-get install clang libclang-rt-14-dev)" >&2; exit 1; }
CC=clang CXX=clang++ cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DBRENIER_BUILD_TESTS=OFF -DBRENIER_BUILD_BENCH=OFF -DBRENIER_BUILD_FUZZ=ON \
  -DCMAKE_CXX_FLAGS="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fsanitize=fuzzer-no-link" >/dev/null
cmake --build "$BUILD" --target fuzz_read_obj fuzz_read_off fuzz_read_ply fuzz_read_stl fuzz_read_freesurfer
F="$ROOT/tests/fixtures"
for fmt in obj off ply stl freesurfer; do
  corpus="$BUILD/corpus-$fmt"
  mkdir -p "$corpus"
  case $fmt in
    freesurfer) seeds=("$F"/*/lh.*) ;;
    *) seeds=("$F"/*/*."$fmt") ;;
  esac
  cp "${seeds[@]}" "$corpus/" 2>/dev/null || true
  echo "== fuzz_read_$fmt for ${SECONDS_EACH}s"
  (cd "$BUILD" && "./tests/fuzz/fuzz_read_$fmt" -max_total_time="$SECONDS_EACH" -max_len=4096 \
     -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 "$corpus" 2>&1 | tail -n 4)
done
