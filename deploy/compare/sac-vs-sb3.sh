#!/usr/bin/env bash
# Our SAC baseline (configs/baselines/sac.toml) against Stable-Baselines3's SAC on one Gymnasium
# task, each with SB3's default settings, SEEDS seeds each, evaluated every EVERY env steps on 10
# deterministic episodes. Writes OUT/TASK/sac-vs-sb3.csv (one row per evaluation) and
# OUT/TASK/table.md (per evaluation step: mean ± std, median, the exact Mann-Whitney test), and
# prints the table. Not a test: a comparison to run by hand.
#   bash deploy/compare/sac-vs-sb3.sh [TASK] [SEEDS] [STEPS] [OUT]
#   bash deploy/compare/sac-vs-sb3.sh Pendulum-v1 8 8000          # docs/results/sac-vs-sb3.md
#   JOBS=1 bash deploy/compare/sac-vs-sb3.sh Hopper-v5 3 50000 /work/compare-runs
# TASK is a Gymnasium id (default Pendulum-v1). Our side trains on `gymnasium:TASK` (the same
# MuJoCo env SB3 steps), except Pendulum-v1, which is our `pendulum` (Gymnasium's exactly).
# Resumable: a run whose OUT/TASK/WHO/seed-N.csv exists is skipped, so running the command again
# after an interruption only redoes the unfinished runs. JOBS runs at a time (default 2), each on
# one thread; EVERY defaults to max(1000, STEPS / 10).
# Needs target/release/selkd (or SELKD_BIN) and the venv deploy/python.sh makes (SB3, Gymnasium,
# MuJoCo).
set -euo pipefail
cd "$(dirname "$0")/../.."
task=${1:-Pendulum-v1}
seeds=${2:-8}
steps=${3:-8000}
out=${4:-runs/sac-vs-sb3}/$task
every=${EVERY:-$(( steps / 10 > 1000 ? steps / 10 : 1000 ))}
jobs=${JOBS:-2}
selkd=${SELKD_BIN:-target/release/selkd}
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
venv=${SELKD_PYTHON_VENV:-$cache/python-venv}
"$venv/bin/python" -c "import stable_baselines3, gymnasium" 2>/dev/null \
    || { echo "sac-vs-sb3: no Stable-Baselines3 in $venv; run bash deploy/python.sh first" >&2; exit 1; }
[ -x "$selkd" ] || { echo "sac-vs-sb3: build first: cargo build --release" >&2; exit 1; }
env=gymnasium:$task
[ "$task" = Pendulum-v1 ] && env=pendulum
mkdir -p "$out/ours" "$out/sb3"
# Each finished run is OUT/TASK/WHO/seed-N.csv (renamed from seed-N.csv.partial, which fills as
# SB3 evaluates; ours shows its progress in seed-N.log) with its wall time in seed-N.seconds.
ours() {
    local s=$1 d="$out/ours/seed-$1" t0=$SECONDS
    rm -rf "$d"
    # SB3's settings: [256, 256], batch 256, τ = 0.005, 1 update per env step; our warm-up must
    # hold one batch, so 256 uniform-random steps where SB3 takes 100.
    "$selkd" train --config configs/baselines/sac.toml --run-dir "$d" \
        --set run.env="$env" --set run.seed="$s" --set run.total_env_steps="$steps" \
        --set run.threads=1 --set run.checkpoint_every=0 --set algo.hidden=[256,256] \
        --set algo.batch_size=256 --set algo.warmup_steps=256 --set algo.polyak=0.995 \
        --set eval.epoch_env_steps="$every" --set eval.episodes=10 > "$d.log" 2>&1 \
        || { echo "sac-vs-sb3: ours seed $s failed; see $d.log" >&2; return 1; }
    awk -F, -v s="$s" 'NR == 1 { for (i = 1; i <= NF; i++) { if ($i == "eval_return_0") c = i; if ($i == "env_steps") e = i }; next }
                       { printf "ours,%s,%s,%s\n", s, $e, $c }' "$d/metrics.csv" > "$out/ours/seed-$s.csv.partial"
    echo $((SECONDS - t0)) > "$out/ours/seed-$s.seconds"
    mv "$out/ours/seed-$s.csv.partial" "$out/ours/seed-$s.csv"
}
theirs() {
    # xargs' bash does not inherit pipefail: without it a failed SB3 run would count as done.
    set -o pipefail
    local s=$1 t0=$SECONDS
    "$venv/bin/python" deploy/compare/sb3_sac.py "$task" "$s" "$steps" "$every" 10 \
        2> "$out/sb3/seed-$s.log" | sed -u 's/^/sb3,/; s/,[^,]*$//' > "$out/sb3/seed-$s.csv.partial" \
        || { echo "sac-vs-sb3: SB3 seed $s failed; see $out/sb3/seed-$s.log" >&2; return 1; }
    echo $((SECONDS - t0)) > "$out/sb3/seed-$s.seconds"
    mv "$out/sb3/seed-$s.csv.partial" "$out/sb3/seed-$s.csv"
}
export -f ours theirs; export out steps every venv selkd env task
for s in $(seq 1 "$seeds"); do
    [ -f "$out/ours/seed-$s.csv" ] || echo "ours $s"
    [ -f "$out/sb3/seed-$s.csv" ] || echo "theirs $s"
done | xargs -r -P "$jobs" -L 1 bash -c '$0 $1'
{ echo "who,seed,env_steps,mean_return"; cat "$out"/ours/seed-*.csv "$out"/sb3/seed-*.csv 2>/dev/null; } > "$out/sac-vs-sb3.csv"
python3 deploy/compare/sac_vs_sb3_table.py "$out/sac-vs-sb3.csv" | tee "$out/table.md"
