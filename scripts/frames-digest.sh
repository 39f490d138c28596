#!/usr/bin/env bash
# Prints one SHA-256 line per scene in scenes/ and backend: the JSON Lines frames a build writes.
# A refactoring that must not change behaviour compares these lines before and after:
#
#   scripts/frames-digest.sh target/release/softbody cpu > /tmp/before-cpu.txt
#   … change, rebuild …
#   scripts/frames-digest.sh target/release/softbody cpu | diff /tmp/before-cpu.txt -
#
# Backends: `cpu` (2 threads; any thread count gives the same bits) and `gpu` (the adapter wgpu
# picks: set WGPU_BACKEND=vulkan for lavapipe on a machine without a GPU). The frames are kept in
# $FRAMES_DIR (default: a temporary directory, removed at the end).
set -euo pipefail
binary=${1:?usage: frames-digest.sh BINARY cpu|gpu [SCENE...]}
backend=${2:?usage: frames-digest.sh BINARY cpu|gpu [SCENE...]}
shift 2
cd "$(dirname "${BASH_SOURCE[0]}")/.."
dir=${FRAMES_DIR:-$(mktemp -d)}
[ -n "${FRAMES_DIR:-}" ] || trap 'rm -rf "$dir"' EXIT
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(scenes/*.toml)
for scene in "${scenes[@]}"; do
  name=$(basename "$scene" .toml)
  out="$dir/$name-$backend.jsonl"
  status=0
  "$binary" run "$scene" --backend "$backend" --threads 2 --quiet --out "$out" || status=$?
  printf '%s  %s %s (exit %s)\n' "$(sha256sum < "$out" | cut -d' ' -f1)" "$name" "$backend" "$status"
done
