#!/usr/bin/env bash
# `softbody bench` of an earlier revision against the working tree's build, alternated run by
# run so that both see the same machine (VMs drift by ±15% within minutes): what a change to a
# vector loop must pass before it is committed (ARCHITECTURE.md, "Recipes").
#
#   scripts/ab-bench.sh REV [SIZES] [THREADS] [ROUNDS]
#   scripts/ab-bench.sh HEAD~1                 # 46³, one and two threads, three rounds
#   scripts/ab-bench.sh e680531 "46 100" 2 5
#   BENCH_ARGS="--integrator rk4" scripts/ab-bench.sh HEAD
#
# REV is built once in a worktree of its own with its own target directory (a cold build of
# the workspace: minutes), under $AB_DIR (default /tmp/softbody-ab); OLD_BIN=path skips that
# build and times the given binary instead. Prints M particle-steps/s per run and, per size and
# thread count, the median of the new ÷ old ratios of the rounds.
set -euo pipefail
cd "$(dirname "$0")/.."
rev=${1:?usage: scripts/ab-bench.sh REV [SIZES] [THREADS] [ROUNDS]}
sizes=${2:-46}
threads=${3:-1 2}
rounds=${4:-3}
work=${AB_DIR:-/tmp/softbody-ab}
old=${OLD_BIN:-}
if [ -z "$old" ]; then
  sha=$(git rev-parse --short "$rev")
  old=$work/target/release/softbody
  if [ ! -x "$old" ] || [ "$(cat "$work/built" 2>/dev/null)" != "$sha" ]; then
    mkdir -p "$work"
    git worktree remove --force "$work/tree" 2>/dev/null || rm -rf "$work/tree"
    git worktree prune
    git worktree add --force --detach "$work/tree" "$rev"
    (cd "$work/tree" && CARGO_TARGET_DIR="$work/target" cargo build --release -p softbody-cli)
    echo "$sha" > "$work/built"
  fi
fi
cargo build --release -p softbody-cli
new=target/release/softbody
rate() {
  # shellcheck disable=SC2086 # BENCH_ARGS is a list of arguments
  "$1" bench --sizes "$2" --threads "$3" --json --quiet ${BENCH_ARGS:-} |
    python3 -c 'import json,sys; print(json.loads(sys.stdin.read())["particle_steps_per_s"]/1e6)'
}
results=$(mktemp)
trap 'rm -f "$results"' EXIT
printf '%5s %7s %5s %10s %10s\n' n threads round old new
for r in $(seq "$rounds"); do
  for n in $sizes; do
    for t in $threads; do
      a=$(rate "$old" "$n" "$t")
      b=$(rate "$new" "$n" "$t")
      printf '%5s %7s %5s %10.2f %10.2f\n' "$n" "$t" "$r" "$a" "$b"
      echo "$n $t $a $b" >> "$results"
    done
  done
done
python3 - "$results" <<'EOF'
import statistics, sys
ratios = {}
for line in open(sys.argv[1]):
    n, t, a, b = line.split()
    ratios.setdefault((int(n), int(t)), []).append(float(b) / float(a))
for (n, t), r in sorted(ratios.items()):
    print(f"{n}³, {t} threads: new/old median {statistics.median(r):.3f} "
          f"(rounds {', '.join(f'{x:.3f}' for x in r)})")
EOF
