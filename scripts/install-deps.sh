#!/usr/bin/env bash
# Installs the build dependencies of libnisflow on Debian 12 (bookworm) with apt-get.
# Runs apt-get directly as root and through sudo otherwise. Safe to run repeatedly.
set -euo pipefail

# Add packages here as the project grows (later: libembree-dev libopenexr-dev libstb-dev
# libexpat1-dev gnuplot).
NF_DEB_PACKAGES=(
    build-essential # gcc, g++, make
    cmake
    pkg-config
    libcmocka-dev   # unit tests
    clang           # second compiler in CI
)

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
