#!/usr/bin/env bash
# Runs the libFuzzer targets of a build made with -DBRENIER_BUILD_FUZZ=ON (clang; scripts/test.sh
# --sanitize address makes one in build-asan/ with ASan + UBSan).
#
#   scripts/fuzz.sh BUILD_DIR [--runs N | --seconds S] [TARGET ...]
#
# Each target starts from its corpus in BUILD_DIR/fuzz/corpus-TARGET, seeded with the fixtures of
# its format and every reproducer in tests/fixtures/fuzz-regressions (so a crash once found is
# tried again each run), and a dictionary of its format's keywords. A crash leaves its input in
# BUILD_DIR/fuzz/artifacts and makes this script exit non-zero. Default: 20000 runs each.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${1:?usage: fuzz.sh BUILD_DIR [--runs N | --seconds S] [TARGET ...]}"
shift
LIMIT=(-runs=20000)
TARGETS=()
while (($#)); do
  case "$1" in
    --runs) LIMIT=(-runs="$2"); shift 2 ;;
    --seconds) LIMIT=(-max_total_time="$2"); shift 2 ;;
    *) TARGETS+=("$1"); shift ;;
  esac
done
((${#TARGETS[@]})) || TARGETS=(fuzz_read_obj fuzz_read_off fuzz_read_ply fuzz_read_stl fuzz_read_freesurfer fuzz_service)
F="$ROOT/tests/fixtures"
mkdir -p "$BUILD/fuzz/artifacts"
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1}"
export LSAN_OPTIONS="suppressions=$ROOT/tests/sanitizers/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
status=0
for t in "${TARGETS[@]}"; do
  exe="$BUILD/tests/fuzz/$t"
  [[ -x $exe ]] || { echo "fuzz.sh: $exe is not built" >&2; exit 2; }
  corpus="$BUILD/fuzz/corpus-$t"
  mkdir -p "$corpus"
  fmt="${t#fuzz_read_}"
  extra=()
  case $t in
    fuzz_read_freesurfer) cp "$F"/*/lh.* "$corpus/" ;;
    fuzz_read_*) cp "$F"/*/*."$fmt" "$corpus/" 2>/dev/null || true ;;
  esac
  [[ $t == fuzz_read_* ]] && cp "$F"/fuzz-regressions/* "$corpus/"
  [[ -f "$ROOT/tests/fuzz/dict/$fmt.dict" ]] && extra+=(-dict="$ROOT/tests/fuzz/dict/$fmt.dict")
  len=4096
  # The service target's inputs are call sequences: let them be long from the start.
  [[ $t == fuzz_service ]] && len=8192 && extra+=(-len_control=0)
  echo "== $t ${LIMIT[*]}"
  if ! "$exe" "${LIMIT[@]}" -max_len=$len -timeout=30 -rss_limit_mb=4096 -print_final_stats=1 \
      -artifact_prefix="$BUILD/fuzz/artifacts/$t-" "${extra[@]}" "$corpus" > "$BUILD/fuzz/$t.log" 2>&1; then
    echo "fuzz.sh: $t failed; its input is in $BUILD/fuzz/artifacts/ (log: $BUILD/fuzz/$t.log)" >&2
    tail -n 40 "$BUILD/fuzz/$t.log" >&2
    status=1
    continue
  fi
  grep -E "stat::number_of_executed_units|cov:" "$BUILD/fuzz/$t.log" | tail -n 2
done
exit $status
