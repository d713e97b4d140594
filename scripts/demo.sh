#!/usr/bin/env bash
# Installs dependencies, builds brenier-compute and runs the main job on embedded defaults:
# it inspects a few real meshes (a scanned face, a closed model, a defective one) and maps
# them conformally onto the unit disk and the unit sphere and area-preservingly onto the
# disk and the sphere, writing the maps into out/.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build}"

bash "$ROOT/scripts/install-deps.sh"
bash "$ROOT/scripts/fetch-data.sh"
cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$BUILD_DIR" -j "$(nproc)" --target brenier-compute
BC="$BUILD_DIR/tools/brenier-compute"
M="$ROOT/data/meshes"

OUT="$ROOT/out"
mkdir -p "$OUT"

for mesh in lion-head.off armadillo.off 3torus.off; do
  echo "== brenier-compute inspect data/meshes/$mesh"
  "$BC" inspect "$M/$mesh"
  echo
done
echo "== brenier-compute inspect --cut-hole data/meshes/bunny00.off (a closed surface opened into a disk)"
"$BC" inspect --cut-hole --domain disk "$M/bunny00.off"
echo
echo "== brenier-compute inspect data/meshes/blobby-shuffled.off (a defective mesh: exit code 2, one line on stderr)"
set +e
"$BC" inspect "$M/blobby-shuffled.off" >/dev/null
echo "exit code $?"
echo "== the same repaired with --fix-orientation --json"
"$BC" inspect --fix-orientation --json "$M/blobby-shuffled.off"
set -e

echo
echo "== brenier-compute map data/meshes/lion-head.off --domain disk -o out/lion-head-disk.obj (conformal, vt per vertex)"
"$BC" map "$M/lion-head.off" --domain disk -o "$OUT/lion-head-disk.obj"
echo
echo "== brenier-compute map data/meshes/armadillo.off --domain sphere -o out/armadillo-sphere.obj"
"$BC" map "$M/armadillo.off" --domain sphere -o "$OUT/armadillo-sphere.obj"
echo
echo "== brenier-compute map data/meshes/bunny00.off --domain disk --cut-hole --json (a closed surface opened and flattened)"
"$BC" map "$M/bunny00.off" --domain disk --cut-hole --json
echo
echo "== brenier-compute map data/meshes/lion-head.off --method area-preserving -o out/lion-head-area.obj (conformal map, then optimal transport)"
"$BC" map "$M/lion-head.off" --method area-preserving -o "$OUT/lion-head-area.obj"
echo
echo "== brenier-compute map data/meshes/bear.off --domain sphere --method area-preserving -o out/bear-sphere-area.ply"
"$BC" map "$M/bear.off" --domain sphere --method area-preserving -o "$OUT/bear-sphere-area.ply"
echo
echo "== brenier-compute distance data/meshes/nefertiti.off data/meshes/mesh_with_border.off --both (conformal Wasserstein, Alg. 5)"
"$BC" distance "$M/nefertiti.off" "$M/mesh_with_border.off" --both
echo
echo "== brenier-compute matrix (six disk meshes, OMT-map distance) -o out/D.csv, then MDS"
"$BC" matrix "$M"/{nefertiti,mesh_with_border,patch-01,patch-13,patch-23,blob}.off -o "$OUT/D.csv" \
  --method omt-linear --cache "$OUT/shape-cache"
cat "$OUT/D.csv"
"$BC" mds "$OUT/D.csv" -o "$OUT/mds.csv"
