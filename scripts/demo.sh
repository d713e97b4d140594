#!/usr/bin/env bash
# Installs dependencies, builds brenier and runs the main job on embedded defaults: it starts
# the service, brenierd (SQLite and a blob directory under out/brenier-data, loopback, an
# ephemeral port), and through the brenier CLI uploads real meshes, maps them conformally
# and area-preservingly onto the disk and the sphere, computes a shape distance and a small
# distance matrix, and prints the results; then the same engine offline (brenier-compute)
# inspects a few meshes and maps more. Everything is written into out/.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build}"

bash "$ROOT/scripts/install-deps.sh"
bash "$ROOT/scripts/fetch-data.sh"
cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$BUILD_DIR" -j "$(nproc)" --target brenier-compute brenierd brenier
BC="$BUILD_DIR/tools/brenier-compute"
M="$ROOT/data/meshes"

OUT="$ROOT/out"
mkdir -p "$OUT"

# ---- the service ----------------------------------------------------------------------------
rm -rf "$OUT/brenierd.port" "$OUT/brenier-data"
"$BUILD_DIR/server/brenierd" --listen 127.0.0.1:0 --data "$OUT/brenier-data" --port-file "$OUT/brenierd.port" \
  > "$OUT/brenierd.log" 2>&1 &
SERVER_PID=$!
trap 'kill -TERM $SERVER_PID 2>/dev/null || true' EXIT
for _ in $(seq 100); do [[ -s "$OUT/brenierd.port" ]] && break; sleep 0.1; done
export BRENIER_SERVER="127.0.0.1:$(cat "$OUT/brenierd.port")"
B="$BUILD_DIR/client/brenier"
echo "== brenierd listening on $BRENIER_SERVER (data in out/brenier-data, log in out/brenierd.log)"
echo
echo "== brenier upload data/meshes/{lion-head,bear,nefertiti}.off"
"$B" upload "$M/lion-head.off" "$M/bear.off" "$M/nefertiti.off"
echo
echo "== brenier map data/meshes/lion-head.off --domain disk -o out/lion-head-disk.obj (conformal, Alg. 1)"
"$B" --progress map "$M/lion-head.off" --domain disk -o "$OUT/lion-head-disk.obj"
echo
echo "== brenier map data/meshes/lion-head.off --method area-preserving -o out/lion-head-area.obj (conformal map, then OMT, Alg. 3)"
"$B" --progress map "$M/lion-head.off" --method area-preserving -o "$OUT/lion-head-area.obj" --report "$OUT/lion-head-area.json"
echo
echo "== brenier map data/meshes/bear.off --domain sphere --method area-preserving -o out/bear-sphere-area.ply"
"$B" map "$M/bear.off" --domain sphere --method area-preserving -o "$OUT/bear-sphere-area.ply"
echo
echo "== brenier distance data/meshes/nefertiti.off data/meshes/mesh_with_border.off (conformal Wasserstein, Alg. 5)"
"$B" distance "$M/nefertiti.off" "$M/mesh_with_border.off"
echo
echo "== brenier matrix (six disk meshes, OMT-map distance, Def. 2.24) -o out/D-service.csv"
"$B" --progress matrix "$M"/{nefertiti,mesh_with_border,patch-01,patch-13,patch-23,blob}.off -o "$OUT/D-service.csv" \
  --method omt-linear
cat "$OUT/D-service.csv"
echo
echo "== brenier jobs"
"$B" jobs
echo
echo "== brenier result JOB --artifact preview.png: the pictures every map and matrix job keeps"
MAP_JOB="$("$B" --json map "$M/lion-head.off" --method area-preserving --no-wait | sed -n 's/.*"id": *"\([0-9a-f]*\)".*/\1/p')"
"$B" watch "$MAP_JOB" >/dev/null
"$B" result "$MAP_JOB" --artifact preview.png -o "$OUT/lion-head-area-service.png"
"$B" result "$MAP_JOB" --artifact report.html -o "$OUT/lion-head-area-service.html"
kill -TERM $SERVER_PID
wait $SERVER_PID
trap - EXIT
echo "== brenierd stopped"
echo

# ---- the same engine offline ------------------------------------------------------------------

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
echo "== brenier-compute map data/meshes/armadillo.off --domain sphere -o out/armadillo-sphere.obj"
"$BC" map "$M/armadillo.off" --domain sphere -o "$OUT/armadillo-sphere.obj"
echo
echo "== pictures: brenier-compute map --picture and render (PNG or SVG)"
"$BC" map "$M/mannequin-devil.off" --method area-preserving --picture "$OUT/mannequin-devil-area.png" \
  --report-html "$OUT/mannequin-devil-area.html"
"$BC" render "$OUT/armadillo-sphere.obj" --surface "$M/armadillo.off" -o "$OUT/armadillo-sphere.png"
"$BC" render "$OUT/lion-head-disk.obj" "$OUT/lion-head-area.obj" -o "$OUT/lion-head.svg"
echo
echo "== brenier-compute map data/meshes/bunny00.off --domain disk --cut-hole --json (a closed surface opened and flattened)"
"$BC" map "$M/bunny00.off" --domain disk --cut-hole --json
echo
echo "== brenier-compute distance data/meshes/nefertiti.off data/meshes/mesh_with_border.off --both (conformal Wasserstein, Alg. 5)"
"$BC" distance "$M/nefertiti.off" "$M/mesh_with_border.off" --both
echo
echo "== brenier-compute matrix (six disk meshes, OMT-map distance) -o out/D.csv, then MDS"
"$BC" matrix "$M"/{nefertiti,mesh_with_border,patch-01,patch-13,patch-23,blob}.off -o "$OUT/D.csv" \
  --method omt-linear --cache "$OUT/shape-cache"
cat "$OUT/D.csv"
"$BC" mds "$OUT/D.csv" -o "$OUT/mds.csv"
"$BC" render "$OUT/D.csv" -o "$OUT/D.png"
echo
echo "== pictures and reports written (the reports open offline in a browser):"
ls -1 "$OUT"/*.png "$OUT"/*.svg "$OUT"/*.html
