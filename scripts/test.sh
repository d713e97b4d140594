#!/usr/bin/env bash
# Installs dependencies, fetches the real meshes, configures, builds and runs every test.
# Exits non-zero on any failure. BUILD_DIR (default build/) and JOBS may be set.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build}"
JOBS="${JOBS:-$(nproc)}"

bash "$ROOT/scripts/install-deps.sh"
bash "$ROOT/scripts/fetch-data.sh"
cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$BUILD_DIR" -j "$JOBS"
cd "$BUILD_DIR"
ctest --output-on-failure -j "$JOBS" --timeout 1200
