#!/usr/bin/env bash
# Builds brenier's image here without a Docker engine and proves it: podman builds
# deploy/Dockerfile (--isolation=chroot) on a debian:bookworm base made with debootstrap when
# podman does not have one (no image registry is needed); then, since `podman run` is refused
# in this sandbox, the image's own programs run from `podman image mount` in a chroot, as its
# user (uid 10001): brenierd serves, `brenier health` (the image's HEALTHCHECK, a grpc.health.v1
# client) answers SERVING, the image's brenier CLI maps a real mesh through it (and fetches the
# job's report.html and preview.png, drawn in the image), and
# brenier-compute runs through the entrypoint. Prints the build time and the image's size.
#
#   scripts/container-test.sh [--no-build] [--tag brenier:dev]
# Needs root (podman, chroot, mounts), podman and debootstrap (apt-get install podman
# debootstrap), Debian's package mirror (the base and the image's apt-get), and
# data/meshes (scripts/fetch-data.sh).
set -euo pipefail
REPO="$(cd "$(dirname "$0")/.." && pwd)"
TAG=brenier:dev BUILD=1
while [[ $# -gt 0 ]]; do
  case "$1" in
    --no-build) BUILD=0; shift ;;
    --tag) TAG="$2"; shift 2 ;;
    *) echo "container-test.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
MESH="$REPO/data/meshes/mushroom.off"
[[ -f "$MESH" ]] || { echo "container-test.sh: $MESH is missing (scripts/fetch-data.sh)" >&2; exit 2; }
for tool in podman debootstrap; do
  command -v "$tool" > /dev/null || [[ -x /usr/sbin/$tool ]] || { echo "container-test.sh: $tool is missing (apt-get install podman debootstrap)" >&2; exit 2; }
done
WORK="$(mktemp -d /tmp/brenier-container-XXXXXX)"
MNT=""
PID=""
cleanup() {
  [[ -n "$PID" ]] && kill "$PID" 2>/dev/null || true
  [[ -n "$MNT" ]] && podman image unmount "$TAG" > /dev/null 2>&1 || true
  rm -rf "$WORK"
}
trap cleanup EXIT
failures=0
check() {  # check CONDITION-EXIT-STATUS WHAT
  if [[ "$1" == 0 ]]; then echo "ok   $2"; else echo "FAIL $2"; failures=$((failures + 1)); fi
}

# ---- the base and the build --------------------------------------------------------------
if ! podman image exists debian:bookworm; then
  echo "container-test: making debian:bookworm with debootstrap from $MIRROR"
  /usr/sbin/debootstrap --variant=minbase bookworm "$WORK/rootfs" "$MIRROR" > "$WORK/debootstrap.log" 2>&1 ||
    { tail -n 20 "$WORK/debootstrap.log" >&2; exit 1; }
  # debootstrap leaves the packages it installed in apt's cache: not part of a base.
  rm -rf "$WORK/rootfs/var/cache/apt/archives/"*.deb "$WORK/rootfs/var/lib/apt/lists/"*
  tar -C "$WORK/rootfs" -c . | podman import - debian:bookworm > /dev/null
  rm -rf "$WORK/rootfs"
fi
if [[ "$BUILD" == 1 ]]; then
  t0=$(date +%s)
  podman build --isolation=chroot --format docker -f "$REPO/deploy/Dockerfile" -t "$TAG" \
    --build-arg REVISION="$(git -C "$REPO" rev-parse HEAD 2>/dev/null || echo unknown)" "$REPO" > "$WORK/build.log" 2>&1 ||
    { tail -n 30 "$WORK/build.log" >&2; exit 1; }
  echo "container-test: built $TAG in $(( $(date +%s) - t0 )) s"
fi
size=$(podman image inspect "$TAG" --format '{{.Size}}')
echo "container-test: $TAG is $((size / 1000000)) MB ($size bytes)"
[[ "$size" -le 300000000 ]]; check $? "the image is at most 300 MB"

# ---- what the image says of itself -------------------------------------------------------
# From here on a check that fails is counted, not fatal: every check runs and says so.
set +e
[[ "$(podman image inspect "$TAG" --format '{{.Config.User}}')" == 10001:10001 ]]; check $? "it runs as uid 10001, not root"
podman image inspect "$TAG" --format '{{json .Config.Healthcheck}}' | grep -q '"brenier","--server","127.0.0.1:50051","health"'
check $? "its HEALTHCHECK asks grpc.health.v1 through brenier health"
[[ -n "$(podman image inspect "$TAG" --format '{{index .Config.Labels "org.opencontainers.image.version"}}')" ]]
check $? "it carries OCI labels"
MNT="$(podman image mount "$TAG")"
for f in usr/local/bin/brenierd usr/local/bin/brenier usr/local/bin/brenier-compute; do
  [[ -x "$MNT/$f" ]]; check $? "it holds /$f"
done
! [[ -e "$MNT/usr/bin/g++" || -e "$MNT/usr/bin/cc" || -e "$MNT/usr/bin/cmake" || -d "$MNT/src" || -d "$MNT/usr/include/CGAL" ]]
check $? "no compiler, build tool, header or source in the runtime stage"

# ---- its programs, run from the mounted image in a chroot as its user ----------------------
mkdir -p "$WORK/data/in"
cp "$MESH" "$REPO/data/meshes/three_peaks.off" "$WORK/data/in/"
chown -R 10001:10001 "$WORK/data"
# The image's root as its container would see it: /data = $WORK/data, /proc, /dev, a tmpfs /tmp,
# then chroot as uid 10001. Every step execs the next: the PID started is the program's.
ENTER='mnt="$1"; data="$2"; shift 2
  mount --bind "$data" "$mnt/data" && mount -t proc proc "$mnt/proc" && mount --rbind /dev "$mnt/dev" &&
    mount -t tmpfs tmpfs "$mnt/tmp" || exit 90
  exec chroot --userspec=10001:10001 "$mnt" env HOME=/data "$@"'
in_image() { unshare -m -- sh -c "$ENTER" sh "$MNT" "$WORK/data" "$@"; }
unshare -m -- sh -c "$ENTER" sh "$MNT" "$WORK/data" /usr/local/bin/brenierd --listen 127.0.0.1:0 \
  --port-file /data/port --data /data/store > "$WORK/brenierd.log" 2>&1 &
PID=$!
for _ in $(seq 200); do [[ -s "$WORK/data/port" ]] && break; sleep 0.1; done
[[ -s "$WORK/data/port" ]]; check $? "the image's brenierd serves"
PORT="$(cat "$WORK/data/port" 2>/dev/null || echo 0)"
[[ "$(ps -o uid= -p "$PID" | tr -d ' ')" == 10001 ]]; check $? "brenierd runs as uid 10001"
[[ "$(in_image brenier --server "127.0.0.1:$PORT" health)" == SERVING ]]; check $? "brenier health (the HEALTHCHECK) says SERVING"
in_image brenier --server "127.0.0.1:$PORT" --json map /data/in/mushroom.off --domain disk --method area-preserving \
  -o /data/mushroom-disk.obj > "$WORK/map.json" 2> "$WORK/map.err"
check $? "the image's brenier CLI maps a real mesh (mushroom, area-preserving) through its brenierd"
[[ "$(grep -c '^vt ' "$WORK/data/mushroom-disk.obj" 2>/dev/null)" == "$(grep -c '^v ' "$WORK/data/mushroom-disk.obj" 2>/dev/null)" &&
   -s "$WORK/data/mushroom-disk.obj" ]]
check $? "its map has one texture coordinate per vertex"
# The map job's pictures and report: Cairo with its font, and three.js (libjs-three), are in
# the image's runtime stage.
JOB="$(in_image brenier --server "127.0.0.1:$PORT" --json jobs | sed -n 's/.*"id": *"\([0-9a-f]\{32\}\)".*/\1/p' | head -n 1)"
in_image brenier --server "127.0.0.1:$PORT" result "$JOB" --artifact report.html -o /data/report.html >/dev/null 2>&1 &&
  grep -q OrbitControls "$WORK/data/report.html" && grep -q 'id="mesh-data"' "$WORK/data/report.html"
check $? "the image writes a map job's report.html with three.js inlined"
in_image brenier --server "127.0.0.1:$PORT" result "$JOB" --artifact preview.png -o /data/preview.png >/dev/null 2>&1 &&
  [[ "$(head -c 4 "$WORK/data/preview.png" | tail -c 3)" == PNG ]]
check $? "and its preview.png"
in_image /usr/local/bin/docker-entrypoint.sh sh -c 'brenier-compute matrix /data/in/*.off -o /data/D.csv' > "$WORK/matrix.log" 2>&1
check $? "brenier-compute runs through the entrypoint (a glob in sh -c)"
[[ "$(head -n 1 "$WORK/data/D.csv" 2>/dev/null)" == "name,mushroom,three_peaks" ]]; check $? "its matrix names both shapes"
in_image /usr/local/bin/docker-entrypoint.sh --help > "$WORK/help.txt" 2>&1
grep -q -- "--executor" "$WORK/help.txt"; check $? "flags given to the entrypoint go to brenierd"
kill -TERM "$PID"
wait "$PID"; rc=$?
PID=""
[[ "$rc" == 0 ]]; check $? "brenierd stops cleanly on SIGTERM"
if [[ "$failures" != 0 ]]; then
  echo "container-test: $failures checks failed; brenierd's log:" >&2
  tail -n 20 "$WORK/brenierd.log" >&2
  cat "$WORK/map.err" "$WORK/matrix.log" >&2 2>/dev/null || true
  exit 1
fi
echo "container-test: all checks passed"
