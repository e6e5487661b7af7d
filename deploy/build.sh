#!/usr/bin/env bash
# Builds the Paddock container images from nothing that must be pulled:
#   paddock-broker:latest and paddock-worker:latest (plus :VERSION tags).
# The release binary is built with cargo, then a minimal root filesystem is assembled
# here (the binary, the C libraries it links, the shipped maps, a non-root user) and
# copied into a `FROM scratch` image. No base image, no registry.
# Usage: deploy/build.sh            (run from anywhere; PADDOCK_BIN=path uses that binary)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
if [ -n "${PADDOCK_BIN:-}" ]; then
    bin="$PADDOCK_BIN"    # a binary already built (the deployment test passes the one it tests)
else
    export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/paddock/target}"
    cargo build --release --locked -p paddock
    bin="$CARGO_TARGET_DIR/release/paddock"
fi
version=$("$bin" --version | awk '{print $2}')

ctx=$(mktemp -d)
trap 'rm -rf "$ctx"' EXIT
root="$ctx/rootfs"
# writable/: the folders the non-root user writes (state volume, caches), copied with
# its ownership
mkdir -p "$root/etc" "$root/keys" "$root/maps" "$ctx/writable/state" "$ctx/writable/tmp"
cp "$bin" "$root/paddock"
strip "$root/paddock" 2>/dev/null || true
# the dynamic loader and every shared library the binary links, at the same paths
for lib in $(ldd "$bin" | grep -oE '/[^ ]+\.so[^ ]*' | sort -u); do
    mkdir -p "$root$(dirname "$lib")"
    cp -L "$lib" "$root$lib"
done
cp -r maps/. "$root/maps/"
rm -f "$root/maps/README.md"
echo 'paddock:x:10001:10001:paddock:/state:/paddock' >"$root/etc/passwd"
echo 'paddock:x:10001:' >"$root/etc/group"
cp deploy/Dockerfile "$ctx/Dockerfile"
for role in broker worker; do
    docker build -q --target "$role" -t "paddock-$role:latest" -t "paddock-$role:$version" "$ctx" >/dev/null
    echo "built paddock-$role:$version ($(docker image inspect -f '{{.Size}}' "paddock-$role:latest" | awk '{printf "%.1f MB", $1/1e6}'))"
done
