#!/usr/bin/env bash
# Build OpenCV's videostab sample (Debian's opencv-doc ships its source) into a git-ignored cache.
# Idempotent: rebuilds only when the binary is missing or older than the source.
# Prints the binary's path on stdout; exits 1 (with a one-line reason) when it cannot be built.
# Packages: opencv-doc (the source), libopencv-dev (headers, libraries, opencv4.pc), g++, pkg-config.
set -euo pipefail
cd "$(dirname "$0")/../.."

CACHE=$PWD/.cache/peers/videostab  # git-ignored; ffviz/bench/methods.py looks for the binary here
BINARY=$CACHE/videostab
SOURCE_DIR=/usr/share/doc/opencv-doc/examples/videostab

source=""
for candidate in "$SOURCE_DIR/videostab.cpp" "$SOURCE_DIR/videostab.cpp.gz"; do
    if [ -f "$candidate" ]; then source=$candidate; break; fi
done
if [ -z "$source" ]; then
    echo "opencv videostab sample source not found under $SOURCE_DIR (apt-get install opencv-doc)" >&2
    exit 1
fi
if [ -x "$BINARY" ] && [ "$BINARY" -nt "$source" ]; then
    echo "$BINARY"
    exit 0
fi
for tool in g++ pkg-config; do
    command -v "$tool" >/dev/null || { echo "$tool not found (apt-get install g++ pkg-config)" >&2; exit 1; }
done
pkg-config --exists opencv4 || { echo "opencv4.pc not found (apt-get install libopencv-dev)" >&2; exit 1; }

mkdir -p "$CACHE"
case "$source" in
    *.gz) gzip -dc "$source" > "$CACHE/videostab.cpp" ;;
    *) cp "$source" "$CACHE/videostab.cpp" ;;
esac
# Build to a temp name and rename: an interrupted build never leaves a broken binary that looks fresh.
# shellcheck disable=SC2046  # pkg-config's flags must split into words
g++ -O2 -std=c++17 -o "$BINARY.tmp" "$CACHE/videostab.cpp" $(pkg-config --cflags --libs opencv4)
mv "$BINARY.tmp" "$BINARY"
echo "$BINARY"
