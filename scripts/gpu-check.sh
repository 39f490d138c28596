#!/usr/bin/env bash
# The prepared check for a machine with an NVIDIA GPU (docs/testing.md, "On a machine with a
# GPU"). Such a machine is lent rarely and for minutes, has no Rust toolchain and no network, so
# the check comes in two halves, with one device call between them (carry: [".gpu-check"]):
#
#   scripts/gpu-check.sh prepare     # here: build, strip and pack what the check needs into
#                                    # .gpu-check/ (ignored by git; carry it to the machine)
#   scripts/gpu-check.sh run OUT     # there: the GPU trials of both tiers, `softbody bench
#                                    # --backend gpu --sizes 46,100,200` and Warp on CUDA
#                                    # beside it; every figure and the adapter's name go to OUT
#
# `run` gives each part a time limit (TESTS_S, BENCH_S, PEERS_S seconds; 240, 90 and 120 by
# default) so that the whole check ends within about eight minutes, and says in
# OUT/summary.txt what each part did. The Vulkan loader (Debian's libvulkan1) travels in
# .gpu-check/ and is unpacked there; NVIDIA's driver provides the rest. Warp (warp-lang
# $WARP_VERSION, the version the published comparison used) travels without its CPU compiler
# (warp-clang.so), which the CUDA device does not use, compressed to fit the 64 MiB a call
# carries.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
PACK=.gpu-check
WARP_VERSION=${WARP_VERSION:-1.5.0}
# The test binaries of the root package and softbody-gpu to carry: by default those holding
# heavy GPU trials (their fast GPU trials run too), which with the binary and Warp fill most of
# the 64 MiB a call carries. SUITES="integrators contact body_contact determinism scenes
# stiff_cube mesh_bodies twins terrain_twin fused chunks body_contact_twin" packs every GPU
# suite (about 44 MB compressed), for a call without Warp (WARP=0).
SUITES=${SUITES:-body_contact contact scenes}

prepare() {
  grep -qxF "/$PACK/" .git/info/exclude 2>/dev/null || echo "/$PACK/" >> .git/info/exclude
  rm -rf "$PACK" && mkdir -p "$PACK/bin" "$PACK/deb"
  cargo build --release -p softbody-cli
  # The suites' executables, by name, as cargo reports them.
  cargo test --release --workspace --no-run --message-format=json 2>/dev/null |
    python3 -c '
import json, sys
wanted = set(sys.argv[1].split())
for line in sys.stdin:
    m = json.loads(line)
    package = m.get("package_id", "").rsplit("#", 1)[-1].split("@")[0]
    if (m.get("reason") == "compiler-artifact" and m.get("executable")
            and package in ("softbody", "softbody-gpu") and m["target"]["name"] in wanted):
        print(m["target"]["name"], m["executable"])
' "$SUITES" | while read -r name exe; do
    strip -o "$PACK/bin/$name" "$exe"
  done
  strip -o "$PACK/bin/softbody" target/release/softbody
  gzip -9 "$PACK"/bin/*
  # The test binaries read scenes/ where they were built; `run` links it there.
  pwd > "$PACK/root"
  (cd "$PACK/deb" && apt-get download libvulkan1 >/dev/null)
  [ "${WARP:-1}" = 0 ] && { report_size; return; }
  local wheels
  wheels=$(mktemp -d)
  python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 \
    --implementation cp --platform manylinux2014_x86_64 -d "$wheels" "warp-lang==$WARP_VERSION"
  (cd "$wheels" && unzip -q ./*.whl && rm -f warp/bin/warp-clang.so ./*.whl &&
    tar -cf - warp | xz -9 -T0 > "$OLDPWD/$PACK/warp.tar.xz")
  rm -rf "$wheels"
  report_size
}

report_size() {
  local size
  size=$(( $(du -sb "$PACK" | cut -f1) + $(git ls-files -z | xargs -0 du -cb | tail -1 | cut -f1) ))
  echo "$PACK: $(du -sh "$PACK" | cut -f1); with the working tree $((size / 1048576)) MiB of the 64 a call carries"
  [ "$size" -le $((64 * 1048576)) ] || { echo "too large for one call: set SUITES to fewer, or WARP=0" >&2; return 1; }
}

run() {
  local out=${1:?usage: gpu-check.sh run OUT}
  mkdir -p "$out"
  local summary="$out/summary.txt"
  : > "$summary"
  note() { echo "$*" | tee -a "$summary"; }
  for f in "$PACK"/deb/*.deb; do dpkg -x "$f" /; done
  ldconfig
  local bin=/tmp/gpu-check-bin
  rm -rf "$bin" && mkdir -p "$bin"
  for f in "$PACK"/bin/*.gz; do gunzip -c "$f" > "$bin/$(basename "$f" .gz)"; done
  chmod +x "$bin"/*
  local root
  root=$(cat "$PACK/root")
  if [ ! -e "$root/scenes" ]; then mkdir -p "$(dirname "$root")" && ln -sfn "$PWD" "$root"; fi
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader > "$out/gpu.txt" 2>&1 || true
  note "gpu: $(cat "$out/gpu.txt")"

  # Both tiers of every GPU trial: on a hardware adapter the heavy ones run by themselves.
  local started=$SECONDS status=0
  for suite in $SUITES; do
    [ -x "$bin/$suite" ] || continue
    local filter=()
    case $suite in twins | terrain_twin | fused | chunks | body_contact_twin) ;; *) filter=(gpu::) ;; esac
    local left=$(( ${TESTS_S:-240} - (SECONDS - started) ))
    if [ "$left" -le 0 ]; then note "tests: out of time before $suite"; status=124; break; fi
    SOFTBODY_REQUIRE_GPU=1 timeout "$left" "$bin/$suite" "${filter[@]}" --include-ignored \
      > "$out/test-$suite.txt" 2>&1 || status=$?
    note "tests: $suite: $(grep -E '^test result' "$out/test-$suite.txt" | tail -1) (exit $status)"
  done
  note "tests: $((SECONDS - started)) s"

  timeout "${BENCH_S:-90}" "$bin/softbody" bench --backend gpu --sizes 46,100,200 --json --quiet \
    > "$out/bench-gpu.jsonl" 2> "$out/bench-gpu.err" || note "bench: exit $?"
  note "bench: $(python3 - "$out/bench-gpu.jsonl" <<'PY' 2>/dev/null
import json, sys
rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
print("; ".join(f"{r['device']}, {r['kernel']}, {r['n']}^3: {r['particle_steps_per_s'] / 1e9:.2f} G particle-steps/s" for r in rows))
PY
)"

  if [ -f "$PACK/warp.tar.xz" ]; then
    mkdir -p /tmp/site && xz -dc "$PACK/warp.tar.xz" | tar -C /tmp/site -xf -
    PYTHONPATH=/tmp/site BIN="$bin/softbody" OUT="$out/peers-gpu.jsonl" timeout "${PEERS_S:-120}" \
      benches/peers-gpu.sh > "$out/peers-gpu.txt" 2>&1 || note "peers: exit $?"
    note "peers: $(tail -n +2 "$out/peers-gpu.txt" | tr '\n' ';')"
  else
    note "peers: no $PACK/warp.tar.xz (run prepare)"
  fi
}

case ${1:-} in
  prepare) prepare ;;
  run) shift; run "$@" ;;
  *) echo "usage: gpu-check.sh prepare | run OUT" >&2; exit 2 ;;
esac
