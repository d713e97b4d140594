#!/usr/bin/env bash
# deploy/kubernetes rendered with `kubectl kustomize` and validated by validate.mjs (Kubernetes
# API schemas, 1.30's field sets, and what the deployment must hold); then mutated copies that
# must be refused, so that the check is seen to fail when it should.
#   test_manifests.sh REPO WORK
# Exit 77 (ctest: skipped, with the reason) when kubectl is not installed (no Debian bookworm
# package has it) or npm cannot install the pinned validators (no npm registry).
set -euo pipefail
REPO="$1" WORK="$2"
HERE="$(cd "$(dirname "$0")" && pwd)"
command -v kubectl > /dev/null || { echo "SKIPPED: kubectl is not installed"; exit 77; }
command -v npm > /dev/null || { echo "SKIPPED: npm is not installed"; exit 77; }
mkdir -p "$WORK"
cp "$HERE/package.json" "$HERE/package-lock.json" "$HERE/validate.mjs" "$WORK/"
if [[ ! -d "$WORK/node_modules/kubernetes-models" ]]; then
  (cd "$WORK" && npm ci --no-audit --no-fund --prefer-offline > npm.log 2>&1) ||
    { echo "SKIPPED: npm could not install the validators (npm registry unreachable?):"; tail -n 3 "$WORK/npm.log"; exit 77; }
fi
kubectl kustomize "$REPO/deploy/kubernetes" > "$WORK/rendered.yaml"
node "$WORK/validate.mjs" "$WORK/rendered.yaml"
refused() {  # refused WHAT SED-EXPRESSION
  sed "$2" "$WORK/rendered.yaml" > "$WORK/mutated.yaml"
  if node "$WORK/validate.mjs" "$WORK/mutated.yaml" > /dev/null 2>&1; then
    echo "FAIL: a manifest with $1 was accepted"; exit 1
  fi
  echo "ok   refused: $1"
}
refused "a misspelt field" 's/readOnlyRootFilesystem/readOnlyRootFilesytem/'
refused "a field newer than Kubernetes 1.30" 's/^  replicas: 2$/  replicas: 2\n  managedBy: x/'
refused "a claim that is not defined" 's/claimName: brenier-shared/claimName: brenier-data/'
refused "an image on :latest" 's|image: \(.*\):0.22.0|image: \1:latest|'
refused "a string where a number goes" 's/backoffLimitPerIndex: 1/backoffLimitPerIndex: one/'
echo "deploy/kubernetes: valid"
