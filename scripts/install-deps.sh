#!/usr/bin/env bash
# Installs every build, test and demo dependency of brenier from Debian bookworm's
# packages. Idempotent: when every package is already there it only checks and exits.
# With --build: only what building needs (the container image's build stage).
set -euo pipefail

# What building brenier needs (the container image's build stage installs only these:
# install-deps.sh --build).
BUILD_PACKAGES=(
  build-essential cmake ninja-build pkg-config git ca-certificates
  libeigen3-dev libcgal-dev libgmp-dev libmpfr-dev libboost-dev
  libopenmesh-dev libsuitesparse-dev
  # L-BFGS (header-only, on Eigen) for the barrier fold repair of area-preserving maps.
  liblbfgspp-dev
  # CHOLMOD's supernodal Cholesky runs on BLAS; with this installed, Debian's alternatives
  # give it OpenBLAS. The pthread build, not the serial one: only it locks its buffers, so
  # two threads may factor at once; the core sets it to one thread per call
  # (single_threaded_blas in core/common/parallel.hpp).
  libopenblas0-pthread
  libspdlog-dev libfmt-dev libcli11-dev nlohmann-json3-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  libsqlite3-dev libssl-dev libcairo2-dev
  # The PostgreSQL store (brenierd --database).
  libpq-dev
)
# What the tests, benchmarks and the demo need beside.
TEST_PACKAGES=(
  # What the programs read at run time beside their libraries (the image's runtime stage
  # installs them too): the pictures' font, and three.js inlined into the HTML reports.
  fonts-dejavu-core libjs-three
  # The HTML report's test in a real browser: headless Chromium driven by Selenium.
  chromium chromium-driver python3-selenium
  # The PostgreSQL the tests start (initdb, pg_ctl).
  postgresql-15
  # The Slurm executor's tests start a real Slurm (munged, slurmctld, slurmd on loopback).
  slurm-wlm munge
  libgtest-dev libgmock-dev googletest libbenchmark-dev
  python3
  # Tests: POT's exact EMD, the independent check of our Wasserstein distances.
  python3-numpy python3-pot
  # Service tests: a Python client generated from our proto (protoc's grpc python plugin),
  # and openssl to make the TLS test's certificates.
  python3-grpcio python3-protobuf openssl
  # The Python client package (clients/python): pip-installed into a venv over Debian's
  # packages; tqdm draws its progress bars.
  python3-venv python3-pip python3-tqdm
  # Sanitizer and fuzz builds (scripts/test.sh --sanitize, scripts/fuzz.sh): clang with its
  # sanitizer and libFuzzer runtimes, LLVM's OpenMP runtime (with Archer, which tells TSan
  # about OpenMP's synchronization) and llvm-symbolizer for readable reports.
  clang libclang-rt-14-dev libomp-14-dev llvm-14
  # The lint test of function sizes (scripts/check-function-sizes.sh).
  universal-ctags
)
PACKAGES=("${BUILD_PACKAGES[@]}")
[[ "${1:-}" == --build ]] || PACKAGES+=("${TEST_PACKAGES[@]}")

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${missing[*]}"
SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
