#!/usr/bin/env bash
# The learner's update rate against the peer's (REDQ's PyTorch critic-ensemble update), interleaved
# in one sitting: each round runs the peer, then each of our variants, at each thread count, and
# every ratio is against the peer's run of the same round and threads (these machines are shared
# and noisy: compare ratios within a sitting, never timings across sittings).
#   bash deploy/bench-learner.sh [ROUNDS] [PEER]
# PEER is the peer's script (default deploy/peer/redq_style_update.py, in this repository).
# Settings, from the environment:
#   THREADS   thread counts to run at (default "1 2")
#   DEVICE    cpu (default) or cuda, for both programs; with cuda, THREADS only sets the CPU side
#   VARIANTS  `selkd bench learner` flag sets, ';'-separated, each shown as its own row (default:
#             fp32 and bf16 at K = 1 and K = 5; bf16 only where the CPU has native bf16, or on cuda)
#   PYTHON    the Python that runs the peer (default: python3 with the libtorch wheel that
#             deploy/setup.sh installed on its path)
#   SELKD     the selkd binary (default target/release/selkd)
# Prints one line per run as it finishes, then a Markdown table for docs/performance.md.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
peer=${2:-deploy/peer/redq_style_update.py}
threads=${THREADS:-1 2}
device=${DEVICE:-cpu}
selkd=${SELKD:-target/release/selkd}
[ -f "$peer" ] || { echo "bench-learner: no peer script at $peer; pass its path as the second argument" >&2; exit 1; }
[ -x "$selkd" ] || { echo "bench-learner: no $selkd: build first (cargo build --release), or set SELKD" >&2; exit 1; }
case "$rounds" in ''|*[!0-9]*|0) echo "bench-learner: ROUNDS must be a positive whole number, not '$rounds'" >&2; exit 1 ;; esac
case "$device" in cpu|cuda|cuda:[0-9]*) ;; *) echo "bench-learner: DEVICE must be cpu or cuda, not '$device'" >&2; exit 1 ;; esac
if [ -n "${PYTHON:-}" ]; then
    python=("$PYTHON")
else
    [ -e .libtorch ] || { echo "bench-learner: no .libtorch: run bash deploy/setup.sh, or set PYTHON to a Python with torch" >&2; exit 1; }
    python=(env "PYTHONPATH=$(dirname "$(readlink -f .libtorch)")" python3)
fi
flags=$(lscpu | awk -F: '/^Flags/ {print $2}')
if [ -n "${VARIANTS:-}" ]; then
    variants=$VARIANTS
elif [ "$device" != cpu ] || [[ " $flags " == *" avx512_bf16 "* ]] || [[ " $flags " == *" amx_bf16 "* ]]; then
    variants="--k 1;--k 1 --critic-matmul bf16;--k 5;--k 5 --critic-matmul bf16"
else
    variants="--k 1;--k 5"
fi
IFS=';' read -r -a variant_list <<<"$variants"

model=$(lscpu | awk -F: '/^Model name/ {gsub(/^ +/, "", $2); print $2; exit}')
isa=""
for f in avx2 avx512f avx512_bf16 amx_bf16; do
    if [[ " $flags " == *" $f "* ]]; then isa="$isa${isa:+ }$f"; fi
done
echo "CPU: $model, $(nproc) cores, ${isa:-no AVX2}; device $device; $(date -u '+%Y-%m-%d %H:%M UTC')"
if [ "$device" != cpu ] && command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | sed 's/^/GPU: /'
fi

# One "round threads row updates/s" record per run, for the summary.
log=$(mktemp)
trap 'rm -f "$log"' EXIT
rate() { awk '/updates\/s/ {v = $NF == "updates/s" ? $(NF-1) : $NF} END {if (v == "") exit 1; print v}'; }
printf '%-5s %-7s %-40s %10s %7s\n' round threads run updates/s ratio
for r in $(seq 1 "$rounds"); do
    for t in $threads; do
        out=$("${python[@]}" "$peer" --threads "$t" --device "$device" 2>&1) \
            || { echo "bench-learner: the peer failed:" >&2; echo "$out" | tail -5 >&2; exit 1; }
        base=$(rate <<<"$out") || { echo "bench-learner: the peer printed no rate:" >&2; echo "$out" | tail -5 >&2; exit 1; }
        printf '%-5s %-7s %-40s %10s %7s\n' "$r" "$t" peer "$base" ""
        echo "$r $t peer $base" >>"$log"
        for i in "${!variant_list[@]}"; do
            v=${variant_list[$i]}
            # shellcheck disable=SC2086 # a variant is a list of flags
            out=$("$selkd" bench learner --threads "$t" --device "$device" $v 2>&1) \
                || { echo "bench-learner: selkd bench learner $v failed:" >&2; echo "$out" | tail -5 >&2; exit 1; }
            ours=$(rate <<<"$out") || { echo "bench-learner: no rate from selkd bench learner $v" >&2; exit 1; }
            printf '%-5s %-7s %-40s %10s %7s\n' "$r" "$t" "selkd $v" "$ours" \
                "$(awk -v a="$ours" -v b="$base" 'BEGIN {printf "%.2fx", a / b}')"
            echo "$r $t $i $ours" >>"$log"
        done
    done
done

# The summary: a row per program, a column per thread count; each cell lists the rounds' rates and
# the range of their ratios to the same round's peer.
echo
awk -v threads="$threads" -v names="peer;$variants" '
    BEGIN { nt = split(threads, ts, " "); nn = split(names, ns, ";") }
    { rate[$1, $2, $3] = $4; if ($1 > rounds) rounds = $1 }
    END {
        printf "| updates/s |"; for (c = 1; c <= nt; c++) printf " threads %s |", ts[c]; print ""
        printf "|---|"; for (c = 1; c <= nt; c++) printf "---|"; print ""
        for (n = 1; n <= nn; n++) {
            key = n == 1 ? "peer" : n - 2
            printf "| %s |", n == 1 ? "peer (REDQ-style PyTorch update)" : "selkd " ns[n]
            for (c = 1; c <= nt; c++) {
                cell = ""; lo = ""; hi = ""
                for (r = 1; r <= rounds; r++) {
                    v = rate[r, ts[c], key]; cell = cell (r > 1 ? ", " : "") v
                    if (key != "peer") {
                        x = v / rate[r, ts[c], "peer"]
                        if (lo == "" || x < lo) lo = x
                        if (hi == "" || x > hi) hi = x
                    }
                }
                if (key != "peer") cell = sprintf("%s (%.2f–%.2f×)", cell, lo, hi)
                printf " %s |", cell
            }
            print ""
        }
    }' "$log"
