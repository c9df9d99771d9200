#!/usr/bin/env bash
# Checks that libnisflow's ABI keeps the last release's: libabigail's abidiff between the
# release's ABI and this tree's, both read from shared libraries built with debug information
# (abidw sees the public types through it). Needs abigail-tools (scripts/install-deps.sh).
# About 2 minutes on 2 cores (one shared build of the library alone).
#
#   scripts/abi-check.sh              compare this tree against the last release
#   scripts/abi-check.sh --baseline   record this tree's ABI as the release's (at a release)
#
# The last release: the newest tag v<major>.<minor>.<patch> reachable from HEAD, built from
# that tag; without such a tag, abi/libnisflow.abi, the ABI recorded with --baseline when the
# version was set (docs/integration.md, "Versions and ABI").
#
# The rule (CHANGELOG.md's header): a release with the same SONAME (libnisflow.so.1 for every
# 1.x; libnisflow.so.0.MINOR before 1.0) must be a superset of the last one's ABI: functions
# and types may be added, none removed or changed. The check fails on an incompatible change
# under the same SONAME, and says so and passes when the SONAME changed (a new major, or
# before 1.0 a new minor), whose ABI then becomes the baseline at its release.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$(pwd)
BASELINE="$ROOT/abi/libnisflow.abi"
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

for tool in abidw abidiff; do
    command -v "$tool" >/dev/null || {
        echo "abi-check: $tool is missing (apt-get install abigail-tools)" >&2
        exit 2
    }
done

# A shared library with debug information from source tree $1 into $2; prints its path.
build_shared() {
    cmake -S "$1" -B "$2" -DBUILD_SHARED_LIBS=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
        -DNF_BUILD_TESTS=OFF -DNF_BUILD_EXAMPLES=OFF -DNF_BUILD_BENCH=OFF >/dev/null
    cmake --build "$2" -j2 --target nisflow >/dev/null
    find "$2" -maxdepth 1 -name 'libnisflow.so.*.*' -type f | head -n 1
}

# abidw of library $1 with headers $2, public types only, into $3.
dump() {
    abidw --headers-dir "$2" --drop-private-types --no-corpus-path --out-file "$3" "$1"
}

soname_of() { sed -n 's/.*soname=.\([^"'"'"']*\).*/\1/p' "$1" | head -n 1; }

lib=$(build_shared "$ROOT" "$TMP/current")
dump "$lib" "$ROOT/include/nisflow" "$TMP/current.abi"

if [ "${1:-}" = --baseline ]; then
    mkdir -p "$(dirname "$BASELINE")"
    cp "$TMP/current.abi" "$BASELINE"
    echo "abi-check: recorded $(soname_of "$BASELINE") in ${BASELINE#"$ROOT"/}"
    exit 0
fi

tag=$(git describe --tags --abbrev=0 --match 'v[0-9]*.[0-9]*.[0-9]*' 2>/dev/null || true)
if [ -n "$tag" ]; then
    git worktree add --detach "$TMP/release" "$tag" >/dev/null 2>&1
    trap 'git -C "$ROOT" worktree remove --force "$TMP/release" >/dev/null 2>&1; rm -rf "$TMP"' EXIT
    old=$(build_shared "$TMP/release" "$TMP/release-build")
    dump "$old" "$TMP/release/include/nisflow" "$TMP/release.abi"
    reference="$TMP/release.abi"
    echo "abi-check: against release $tag"
elif [ -f "$BASELINE" ]; then
    reference="$BASELINE"
    echo "abi-check: against ${BASELINE#"$ROOT"/} (no release tag in this clone)"
else
    echo "abi-check: no release tag and no ${BASELINE#"$ROOT"/}: nothing to compare" >&2
    exit 2
fi

old_soname=$(soname_of "$reference")
new_soname=$(soname_of "$TMP/current.abi")
if [ "$old_soname" != "$new_soname" ]; then
    echo "abi-check: the SONAME changed ($old_soname -> $new_soname): an ABI break is allowed;"
    echo "abi-check: record the new ABI at its release (scripts/abi-check.sh --baseline)"
    exit 0
fi

set +e
abidiff --no-added-syms "$reference" "$TMP/current.abi" >"$TMP/diff.txt" 2>&1
rc=$?
set -e
# abidiff's status is a bit field: 1 error, 2 usage, 4 ABI change, 8 incompatible change.
if (( rc & 3 )); then
    cat "$TMP/diff.txt" >&2
    echo "abi-check: abidiff failed (status $rc)" >&2
    exit 2
fi
# Added functions are not reported (--no-added-syms); anything else (a function or type
# removed or changed, a struct's layout or size) breaks programs built against the release.
if (( rc & 12 )); then
    cat "$TMP/diff.txt"
    echo "abi-check: FAILED: the ABI changed under the same SONAME ($new_soname)" >&2
    exit 1
fi
echo "abi-check: $new_soname keeps the last release's ABI (additions allowed)"
