#!/usr/bin/env bash
# Installs the build dependencies of libnisflow on Debian 12 (bookworm) with apt-get.
# Runs apt-get directly as root and through sudo otherwise. Safe to run repeatedly.
#
#   ./scripts/install-deps.sh           what the build, the tests and the tracer need
#   ./scripts/install-deps.sh --study   also gnuplot and python3, for scripts/paper-study.sh
#                                       and scripts/equal-time.sh, and patch, for
#                                       scripts/point-cost-study.sh
set -euo pipefail

# Add packages here as the project grows.
NF_DEB_PACKAGES=(
    build-essential # gcc, g++, make
    cmake
    pkg-config
    libcmocka-dev   # unit tests
    clang           # second compiler in CI
    clang-format    # CI checks that include/ and src/ keep .clang-format's style
    libclang-rt-14-dev # clang's sanitizer and libFuzzer runtimes (.ci/robustness)
    abigail-tools   # abidw, abidiff: CI checks the ABI against the last release's
    # The example path tracer (examples/tracer/); without them it is skipped at configure time.
    libembree-dev   # Embree 3: ray intersection
    libopenexr-dev  # OpenEXR 3: the OpenEXRCore C API for HDR images
    libstb-dev      # stb_image, stb_image_write: JPEG textures, PNG previews
    libexpat1-dev   # expat: the scene XML
    # Optional for the tracer: MPI, to train one model over several processes or machines
    # (docs/distributed.md); without it nf_tracer is one process.
    libopenmpi-dev
    openmpi-bin     # mpirun
)

case "${1:-}" in
    "") ;;
    --study) NF_DEB_PACKAGES+=(gnuplot-nox python3 patch) ;;
    *) echo "usage: $0 [--study]" >&2; exit 2 ;;
esac

if [ "$(id -u)" -eq 0 ]; then
    SUDO=()
elif command -v sudo >/dev/null 2>&1; then
    SUDO=(sudo)
else
    echo "install-deps.sh: not root and sudo is not available" >&2
    exit 1
fi

export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive \
    apt-get install -y -q --no-install-recommends "${NF_DEB_PACKAGES[@]}"
