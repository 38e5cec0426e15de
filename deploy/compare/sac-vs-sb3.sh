#!/usr/bin/env bash
# Our SAC baseline (configs/baselines/sac.toml) against Stable-Baselines3's SAC on Pendulum, each
# with SB3's default settings, SEEDS seeds each, evaluated every 1000 env steps on 10
# deterministic episodes; prints a table per env step (mean ± std, median) and writes
# OUT/sac-vs-sb3.csv. Not a test: a comparison to run by hand (about 15 min on 2 cores).
#   bash deploy/compare/sac-vs-sb3.sh [SEEDS] [STEPS] [OUT]
# Needs target/release/selkd and the torch deploy/setup.sh installs; makes a venv with
# stable-baselines3 and gymnasium on first use.
set -euo pipefail
cd "$(dirname "$0")/../.."
seeds=${1:-8}
steps=${2:-8000}
out=${3:-runs/sac-vs-sb3}
selkd=${SELKD_BIN:-target/release/selkd}
torch_dir=${SELKD_CACHE:-$HOME/.cache/selkd}/torch-2.11.0
venv=${SELKD_SB3_VENV:-$HOME/.cache/selkd/sb3-venv}
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import stable_baselines3" 2>/dev/null; then
    echo "sac-vs-sb3: making $venv (stable-baselines3, gymnasium; torch from $torch_dir)" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet gymnasium numpy pandas cloudpickle matplotlib
    "$venv/bin/pip" install --quiet --no-deps stable-baselines3
    echo "$torch_dir" > "$("$venv/bin/python" -c 'import site; print(site.getsitepackages()[0])')/selkd-torch.pth"
fi
[ -x "$selkd" ] || { echo "sac-vs-sb3: build first: cargo build --release" >&2; exit 1; }
mkdir -p "$out"
ours() {
    local s=$1 d="$out/ours/seed-$1"
    rm -rf "$d"
    # SB3's settings: [256, 256], batch 256, τ = 0.005, 1 update per env step; our warm-up must
    # hold one batch, so 256 uniform-random steps where SB3 takes 100.
    "$selkd" train --config configs/baselines/sac.toml --run-dir "$d" \
        --set run.env=pendulum --set run.seed="$s" --set run.total_env_steps="$steps" \
        --set run.threads=1 --set run.checkpoint_every=0 --set algo.hidden=[256,256] \
        --set algo.batch_size=256 --set algo.warmup_steps=256 --set algo.polyak=0.995 \
        --set eval.epoch_env_steps=1000 --set eval.episodes=10 > /dev/null 2>&1
    awk -F, -v s="$s" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == "eval_return_0") c = i; next }
                       { printf "ours,%s,%s,%s\n", s, $2, $c }' "$d/metrics.csv"
}
theirs() {
    "$venv/bin/python" deploy/compare/sb3_sac_pendulum.py "$1" "$steps" | sed 's/^/sb3,/'
}
export -f ours theirs; export out steps venv selkd
{
    echo "who,seed,env_steps,mean_return"
    for s in $(seq 1 "$seeds"); do echo "ours $s"; echo "theirs $s"; done |
        xargs -P 2 -L 1 bash -c '$0 $1'
} > "$out/sac-vs-sb3.csv"
python3 - "$out/sac-vs-sb3.csv" <<'PY'
import csv, statistics as st, sys
rows = list(csv.DictReader(open(sys.argv[1])))
by = {}
for r in rows:
    by.setdefault((int(r["env_steps"]), r["who"]), []).append(float(r["mean_return"]))
print(f"{'env steps':>9}  {'ours mean ± std (median)':>28}  {'SB3 mean ± std (median)':>28}")
for step in sorted({k[0] for k in by}):
    cells = []
    for who in ["ours", "sb3"]:
        v = by.get((step, who), [])
        cells.append(f"{st.mean(v):8.0f} ± {st.stdev(v):4.0f} ({st.median(v):6.0f}) n={len(v)}" if len(v) > 1 else "–")
    print(f"{step:>9}  {cells[0]:>28}  {cells[1]:>28}")
PY
