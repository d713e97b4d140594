#!/usr/bin/env bash
# A distance matrix as a Slurm job array: each task computes one tile; a dependent job
# merges them (byte-identical to a single run).
#   sbatch --array=0-31 deploy/slurm-matrix.sh shapes/ out/
#   sbatch --dependency=afterok:<array job id> --wrap "brenier-compute merge out/tile-*.json -o out/D.csv"
#SBATCH --job-name=brenier-matrix
#SBATCH --cpus-per-task=2
#SBATCH --mem=4G
set -euo pipefail
SHAPES="$1" OUT="$2"
COUNT=$((SLURM_ARRAY_TASK_MAX + 1))
mkdir -p "$OUT"
brenier-compute matrix "$SHAPES"/*.off --jobs "$SLURM_CPUS_PER_TASK" --cache "$OUT/cache" \
  --tile "$SLURM_ARRAY_TASK_ID/$COUNT" -o "$OUT/tile-$SLURM_ARRAY_TASK_ID.json"
