#!/usr/bin/env bash
# Side by side on a GPU: `softbody bench --backend gpu` (wgpu, f32) and Warp on CUDA (the peer
# script's Warp cube with device = "cuda:0", f32), size by size on the same machine. Writes JSON
# lines to $OUT (default bench-peers-gpu.jsonl) and prints million particle-steps/s.
#
#   pip install numpy warp-lang && cargo build --release && benches/peers-gpu.sh
#   SIZES="46 100" benches/peers-gpu.sh
#   GPU_ROUTE=per-spring benches/peers-gpu.sh   # softbody's other designs: gather, per-spring
#
# The Warp side is a copy of PEER_SCRIPT (default ../shared/peers/mass_spring_peer.py beside the
# repository) with its device changed to cuda:0, timed over PEER_PSTEPS particle-steps per repeat
# (the script's own step counts are sized for a CPU: 10 steps of 100³ would time the launch).
# Warp releases before `@wp.kernel(module=...)` existed run the copy with that argument dropped.
# WARP_LAUNCH=plain (default) has step() call wp.launch for its two kernels; =recorded keeps the
# script's recorded launches (`record_cmd=True`), which Warp 1.5.0 on CUDA failed with an
# illegal memory access at 100³ (at 46³ both gave the same rate).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python3}
PEER_SCRIPT=${PEER_SCRIPT:-../shared/peers/mass_spring_peer.py}
SIZES=${SIZES:-46 100 200}
GPU_ROUTE=${GPU_ROUTE:-auto}
PEER_PSTEPS=${PEER_PSTEPS:-2000000000}
OUT=${OUT:-bench-peers-gpu.jsonl}
BIN=${BIN:-target/release/softbody}
copy=$(mktemp --suffix=.py)
trap 'rm -f "$copy"' EXIT
sed 's/^\( *dev = \)"cpu"$/\1"cuda:0"/' "$PEER_SCRIPT" > "$copy"
grep -q 'dev = "cuda:0"' "$copy" || { echo "peers-gpu: no 'dev = \"cpu\"' line in $PEER_SCRIPT" >&2; exit 2; }
if [ "${WARP_LAUNCH:-plain}" = plain ]; then
  python3 - "$copy" <<'PY'
import sys
path = sys.argv[1]
text = open(path).read()
recorded = "        cmd_s.launch()\n        cmd_i.launch()\n"
plain = (
    "        wp.launch(springs_k, dim=S, inputs=[x, v, sa, sb, rest, scal(KS), scal(KD), f], device=dev)\n"
    "        wp.launch(integrate_k, dim=N, inputs=[x, v, f, scal(float(n ** 3)), vec(0.0, GY, 0.0),\n"
    "                  scal(DT), scal(RESTITUTION), int(bool(explicit))], device=dev)\n"
)
if recorded not in text:
    sys.exit(f"peers-gpu: no recorded launches in step() of {path}")
open(path, "w").write(text.replace(recorded, plain))
PY
fi
if ! "$PY" -c 'import inspect, warp; raise SystemExit("module" not in inspect.signature(warp.kernel).parameters)'; then
  sed -i 's/, module="unique")/)/' "$copy"
fi
: > "$OUT"
"$BIN" bench --backend gpu --sizes 10 --quiet | head -1 >&2 # names the adapter
printf '%5s %12s %12s   (million particle-steps/s, f32, symplectic Euler; Warp best of 3)\n' \
  n softbody warp-cuda
for n in $SIZES; do
  ours=$("$BIN" bench --backend gpu --gpu-route "$GPU_ROUTE" --sizes "$n" --json --quiet | tee -a "$OUT" |
    python3 -c 'import json,sys; print(json.loads(sys.stdin.read())["particle_steps_per_s"])')
  steps=$((PEER_PSTEPS / (n * n * n)))
  line=$("$PY" "$copy" run --backend warp --n "$n" --fp f32 --dt stable --repeats 3 --steps "$steps" | tail -1)
  echo "$line" >> "$OUT"
  printf '%5s %12.1f %12.1f\n' "$n" "$(python3 -c "print($ours/1e6)")" \
    "$(echo "$line" | python3 -c 'import json,sys; print(json.loads(sys.stdin.read())["pstep_per_s_best"]/1e6)')"
done
