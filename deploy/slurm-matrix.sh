#!/usr/bin/env bash
# A distance matrix over a folder of meshes as a Slurm job array, without brenierd: each array
# task computes one tile (its share of the shapes into a shared cache first, then its pairs);
# a merge job that depends on the array assembles the tiles into the matrix, byte-identical to
# one `brenier-compute matrix` run over the same files.
#
#   deploy/slurm-matrix.sh [--tasks K] [--cpus C] [--mem M] [--sbatch "OPTIONS"] [--wait] \
#                          SHAPES_DIR OUT_DIR [-- MATRIX_OPTIONS...]
#
# Run it on a login node; SHAPES_DIR and OUT_DIR must be on storage every node mounts.
#   --tasks K        array tasks (tiles), default 16
#   --cpus C         CPUs per task (brenier-compute --jobs), default 1
#   --mem M          memory per task (sbatch --mem), default 2G
#   --sbatch "..."   further sbatch options for both jobs (partition, account, time, ...)
#   --wait           return once the merge job has finished (its exit status)
#   MATRIX_OPTIONS   brenier-compute matrix options (--method, --domain, --tolerance, ...)
# Writes OUT_DIR/D.csv (and OUT_DIR/tile-*.json, OUT_DIR/cache/, OUT_DIR/logs/). The file
# list is fixed once, in OUT_DIR/shapes.txt, so every task sees the same shapes in the same
# order. BRENIER_COMPUTE names the binary when it is not on the nodes' PATH.
set -euo pipefail
usage() { { printf 'usage: '; sed -n '7,8p' "$0" | sed 's/^# *//'; } >&2; exit 2; }
COMPUTE="${BRENIER_COMPUTE:-brenier-compute}"

# ---- inside Slurm: one array task, or the merge --------------------------------------------
if [[ "${1:-}" == --task ]]; then
  OUT="$2" COUNT="$3"; shift 3
  mapfile -t files < "$OUT/shapes.txt"
  exec "$COMPUTE" matrix "${files[@]}" "$@" --jobs "${SLURM_CPUS_PER_TASK:-1}" --cache "$OUT/cache" \
    --tile "${SLURM_ARRAY_TASK_ID:-0}/$COUNT" -o "$OUT/tile-${SLURM_ARRAY_TASK_ID:-0}.json"
fi
if [[ "${1:-}" == --merge ]]; then
  OUT="$2" COUNT="$3"
  tiles=()
  for ((k = 0; k < COUNT; k++)); do tiles+=("$OUT/tile-$k.json"); done
  exec "$COMPUTE" merge "${tiles[@]}" -o "$OUT/D.csv"
fi

# ---- on the login node: submit the array and its merge ---------------------------------------
tasks=16 cpus=1 mem=2G extra="" wait=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --tasks) tasks="${2:?--tasks needs a number}"; shift 2 ;;
    --cpus) cpus="${2:?--cpus needs a number}"; shift 2 ;;
    --mem) mem="${2:?--mem needs a size}"; shift 2 ;;
    --sbatch) extra="${2?--sbatch needs options}"; shift 2 ;;
    --wait) wait="--wait"; shift ;;
    -h|--help) usage ;;
    --) break ;;
    -*) echo "slurm-matrix.sh: unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[[ $# -ge 2 ]] || usage
SHAPES="$1" OUT="$2"; shift 2
[[ "${1:-}" == -- ]] && shift
[[ -d "$SHAPES" ]] || { echo "slurm-matrix.sh: $SHAPES is not a folder" >&2; exit 2; }
[[ "$tasks" =~ ^[1-9][0-9]*$ ]] || { echo "slurm-matrix.sh: --tasks must be a positive number, not $tasks" >&2; exit 2; }
command -v sbatch > /dev/null || { echo "slurm-matrix.sh: sbatch is not on PATH (run it where Slurm's commands are)" >&2; exit 2; }
mkdir -p "$OUT/logs"
OUT="$(cd "$OUT" && pwd)"
SHAPES="$(cd "$SHAPES" && pwd)"
find "$SHAPES" -maxdepth 1 -type f \( -iname '*.off' -o -iname '*.obj' -o -iname '*.ply' -o -iname '*.stl' \) |
  LC_ALL=C sort > "$OUT/shapes.txt"
n="$(wc -l < "$OUT/shapes.txt")"
[[ "$n" -ge 2 ]] || { echo "slurm-matrix.sh: $SHAPES holds $n meshes (.off .obj .ply .stl); a matrix needs 2" >&2; exit 2; }
pairs=$((n * (n - 1) / 2))
((tasks > pairs)) && tasks=$pairs
rm -f "$OUT"/tile-*.json "$OUT/D.csv"
self="$(cd "$(dirname "$0")" && pwd)/$(basename "$0")"
# shellcheck disable=SC2086  # --sbatch's options are words on purpose
array="$(sbatch --parsable --job-name=brenier-matrix --array="0-$((tasks - 1))" --cpus-per-task="$cpus" \
  --mem="$mem" --output="$OUT/logs/tile-%a.out" --export=ALL $extra "$self" --task "$OUT" "$tasks" "$@")"
array="${array%%;*}"
# shellcheck disable=SC2086
merge="$(sbatch --parsable $wait --job-name=brenier-merge --dependency="afterok:$array" --kill-on-invalid-dep=yes \
  --output="$OUT/logs/merge.out" --export=ALL $extra "$self" --merge "$OUT" "$tasks")"
echo "matrix of $n shapes ($pairs pairs): array ${array} of $tasks tasks, merge job ${merge%%;*} -> $OUT/D.csv"
if [[ -n "$wait" && ! -s "$OUT/D.csv" ]]; then
  failed=()
  for ((k = 0; k < tasks; k++)); do [[ -s "$OUT/tile-$k.json" ]] || failed+=("$k"); done
  why="$(tail -n 1 "$OUT/logs/tile-${failed[0]:-0}.out" 2>/dev/null || true)"
  echo "slurm-matrix.sh: no matrix: tiles ${failed[*]:-none} failed (logs in $OUT/logs; tile ${failed[0]:-0}: ${why:-no log})" >&2
  exit 1
fi
