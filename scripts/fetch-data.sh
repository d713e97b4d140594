#!/usr/bin/env bash
# Installs Debian's libcgal-demo and unpacks the real meshes it ships
# (/usr/share/doc/libcgal-dev/data.tar.gz, directory data/meshes) into data/meshes/.
# data/ is git-ignored: these files are never committed.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DEST="$ROOT/data"
TARBALL=/usr/share/doc/libcgal-dev/data.tar.gz

if [[ -f "$DEST/meshes/.complete" ]]; then
  echo "fetch-data: $(find "$DEST/meshes" -type f ! -name .complete | wc -l) files already in data/meshes"
  exit 0
fi

if [[ ! -f "$TARBALL" ]]; then
  SUDO=""
  if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
  export DEBIAN_FRONTEND=noninteractive
  if ! $SUDO apt-get install -y -qq --no-install-recommends libcgal-demo; then
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq --no-install-recommends libcgal-demo
  fi
fi
[[ -f "$TARBALL" ]] || { echo "fetch-data: $TARBALL missing after installing libcgal-demo" >&2; exit 1; }

mkdir -p "$DEST"
tmp="$(mktemp -d "$DEST/.unpack.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
tar -xzf "$TARBALL" -C "$tmp" --wildcards '*data/meshes/*'
src="$(find "$tmp" -type d -path '*data/meshes' | head -n1)"
[[ -n "$src" ]] || { echo "fetch-data: no data/meshes directory inside $TARBALL" >&2; exit 1; }
rm -rf "$DEST/meshes"
mv "$src" "$DEST/meshes"
touch "$DEST/meshes/.complete"
echo "fetch-data: $(find "$DEST/meshes" -type f ! -name .complete | wc -l) files in data/meshes"
