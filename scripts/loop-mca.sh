#!/usr/bin/env bash
# What bounds a hot loop on a given core: llvm-mca's scheduling model run on the loop that the
# release binary actually contains (not on a recompiled copy), cycles per iteration and the
# pressure on each execution port. It found that the stencil's AVX2 loop is bound by the two
# multiply pipes on Zen 3 (docs/lab/explicit-stencil.md).
#
#   cargo build --release
#   scripts/loop-mca.sh                                  # the AVX2 stencil's springs, this CPU
#   MCPU=znver4 scripts/loop-mca.sh                      # another core's model
#   FUNCTION=stencil::avx512::compute_row scripts/loop-mca.sh
#   FUNCTION=stencil::avx::sum_row MARK=vaddpd scripts/loop-mca.sh
#
# FUNCTION: part of the demangled symbol; MARK: an instruction that the loop must contain (the
# smallest loop of FUNCTION containing it is taken); MCPU: llvm-mca's -mcpu (default: native).
# Needs objdump, nm and llvm-mca (Debian: binutils, llvm). Exit status 2: nothing to model.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-target/release/softbody}
FUNCTION=${FUNCTION:-stencil::avx::compute_row}
MARK=${MARK:-vsqrtpd}
MCPU=${MCPU:-native}
MCA=${MCA:-$(command -v llvm-mca || ls /usr/bin/llvm-mca-* 2>/dev/null | sort -V | tail -1)}
[ -x "$MCA" ] || { echo "loop-mca: llvm-mca not found (apt-get install llvm)" >&2; exit 2; }

# The function's address range, from the symbol table.
read -r start size name < <(nm -C --size-sort -S "$BIN" | awk -v f="$FUNCTION" 'index($0, f) { print $1, $2, $4; exit }') || true
[ -n "${start:-}" ] || { echo "loop-mca: no symbol matching '$FUNCTION' in $BIN" >&2; exit 2; }
stop=$(printf '0x%x' $((0x$start + 0x$size)))

listing=$(mktemp)
loop=$(mktemp)
trap 'rm -f "$listing" "$loop"' EXIT
objdump -d --no-show-raw-insn --start-address="0x$start" --stop-address="$stop" "$BIN" |
  grep -P '^\s+[0-9a-f]+:\t' | sed -E 's/^\s+([0-9a-f]+):\t/\1\t/; s/ *#.*//; s/ +<[^>]*>//' > "$listing"

# Loops are backward conditional jumps; take the smallest one whose body holds MARK.
python3 - "$listing" "$MARK" > "$loop" <<'EOF'
import re, sys
rows = [line.rstrip("\n").split("\t", 1) for line in open(sys.argv[1])]
rows = [(int(a, 16), ins.strip()) for a, ins in rows]
best = None
for i, (addr, ins) in enumerate(rows):
    m = re.match(r"j(?!mp)\w+\s+([0-9a-f]+)$", ins)
    if not m or int(m.group(1), 16) >= addr:
        continue
    body = [r for r in rows[: i + 1] if r[0] >= int(m.group(1), 16)]
    if any(sys.argv[2] in b for _, b in body) and (best is None or len(body) < len(best)):
        best = body
if best is None:
    print(f"loop-mca: no loop containing {sys.argv[2]}", file=sys.stderr)
    sys.exit(2)
# The closing jump's target is meaningless to llvm-mca, which models one iteration after
# another anyway: drop it.
print("\n".join(ins for _, ins in best[:-1]))
EOF

echo "$name: a loop of $(wc -l < "$loop") instructions, llvm-mca -mcpu=$MCPU"
"$MCA" -mcpu="$MCPU" -iterations=500 -resource-pressure=true -timeline=false \
  -instruction-info=false "$loop" 2>/dev/null |
  awk '/^Iterations:/ { it = $2 } /^Total Cycles:/ { printf "cycles per iteration: %.2f\n", $3 / it }
       /^Block RThroughput/ || /^Resources:/, /^$/ { print }
       /^Resource pressure per iteration:/ { p = 3 } p-- > 0 { print }'
