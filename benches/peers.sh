#!/usr/bin/env bash
# Side by side: `softbody bench` and the peers (Warp CPU, Taichi CPU, NumPy) on the same cube,
# size by size, interleaved so that both see the same machine. Writes JSON lines to $OUT
# (default bench-peers.jsonl) and prints a table of million particle-steps/s (best of 3).
#
#   python3 -m venv /tmp/peers-venv && /tmp/peers-venv/bin/pip install numpy warp-lang taichi
#   cargo build --release && benches/peers.sh            # sizes 10 22 46 100
#   SIZES="22 46" PEERS="warp" benches/peers.sh
#
# PEER_SCRIPT defaults to ../shared/peers/mass_spring_peer.py beside the repository.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-/tmp/peers-venv/bin/python}
PEER_SCRIPT=${PEER_SCRIPT:-../shared/peers/mass_spring_peer.py}
SIZES=${SIZES:-10 22 46 100}
PEERS=${PEERS:-warp taichi numpy}
THREADS=${THREADS:-$(nproc)}
OUT=${OUT:-bench-peers.jsonl}
BIN=${BIN:-target/release/softbody}
: > "$OUT"
best() { python3 -c 'import json,sys; print(max(json.loads(l)[sys.argv[1]] for l in sys.stdin if l.strip()))' "$1"; }
printf '%5s %10s' n softbody
for p in $PEERS; do printf ' %10s' "$p"; done
printf '   (million particle-steps/s, f64, symplectic Euler, best of 3)\n'
for n in $SIZES; do
  ours=$(for r in 1 2 3; do "$BIN" bench --sizes "$n" --threads "$THREADS" --json --quiet; done | tee -a "$OUT" | best particle_steps_per_s)
  printf '%5s %10.2f' "$n" "$(python3 -c "print($ours/1e6)")"
  for p in $PEERS; do
    extra=()
    [ "$p" = taichi ] && extra=(--threads "$THREADS")
    line=$("$PY" "$PEER_SCRIPT" run --backend "$p" --n "$n" --fp f64 --dt stable --repeats 3 "${extra[@]}" 2>/dev/null | tail -1)
    echo "$line" >> "$OUT"
    printf ' %10.2f' "$(echo "$line" | python3 -c 'import json,sys; print(json.loads(sys.stdin.read())["pstep_per_s_best"]/1e6)')"
  done
  printf '\n'
done
