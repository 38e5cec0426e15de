#!/usr/bin/env bash
# `selkd train` on Gymnasium's MuJoCo Hopper-v5 against our rapier `hopper`, same config, one
# sitting: SECONDS-long runs of configs/paper.toml (K = 5 workers, N = 10, G = 20), ROUNDS rounds
# in A B / B A order so that drift in the machine's load falls on both; then the bridge's cost
# per step: `selkd bench env gymnasium:ID` (the env stepped through the bridge) against Gymnasium's
# own Python loop (deploy/gym_env_steps.py), interleaved, BRIDGE_ROUNDS rounds (default 5), on
# Hopper-v5 (STEPS steps) and on SelkdEcho-v0 (gymnasium/tests/python, a step that does almost
# nothing, so that the difference is the bridge's own cost; 50 000 steps).
#   bash deploy/bench-gym-train.sh [SECONDS] [ROUNDS] [OUT] [STEPS]      (defaults 180 2 runs/bench-gym-train 20000)
# Prints per run the env steps/s and critic updates/s (from logs/progress.jsonl: warm-up, the whole
# run, and after the 5000 warm-up transitions), and the bridge's env steps/s. Needs
# target/release/selkd and the venv deploy/python.sh makes. docs/results/gymnasium-throughput.md.
set -euo pipefail
cd "$(dirname "$0")/.."
secs=${1:-180}
rounds=${2:-2}
out=${3:-runs/bench-gym-train}
steps=${4:-20000}
selkd=${SELKD_BIN:-target/release/selkd}
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
venv=${SELKD_PYTHON_VENV:-$cache/python-venv}
[ -x "$selkd" ] || { echo "bench-gym-train: build first: cargo build --release" >&2; exit 1; }
mkdir -p "$out"
lscpu | grep -m1 'Model name' >&2 || true
for r in $(seq 1 "$rounds"); do
    envs=(hopper gymnasium:Hopper-v5)
    [ $((r % 2)) = 0 ] && envs=(gymnasium:Hopper-v5 hopper)
    for env in "${envs[@]}"; do
        d="$out/${env//:/-}-$r"
        rm -rf "$d"
        # SIGTERM after SECONDS: selkd stops the run in order (exit 143); the progress log stays.
        timeout "$secs" "$selkd" train --config configs/paper.toml --run-dir "$d" \
            --set run.env="$env" --set run.checkpoint_every=0 > "$d.log" 2>&1 || true
        python3 - "$d/logs/progress.jsonl" "$env" "$r" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
last = rows[-1]
warm = next((x for x in rows if x["critic_updates"] > 0), None)
before = rows[rows.index(warm) - 1] if warm and rows.index(warm) > 0 else None
def rate(a, b, k):
    return (b[k] - a[k]) / (b["wall_s"] - a["wall_s"]) if b["wall_s"] > a["wall_s"] else float("nan")
zero = {"env_steps": 0, "critic_updates": 0, "wall_s": 0.0}
w = rate(warm, last, "env_steps") if warm else float("nan")
u = rate(warm, last, "critic_updates") if warm else float("nan")
warmup = rate(zero, before, "env_steps") if before else float("nan")
print(f"{sys.argv[2]:>20} round {sys.argv[3]}: {last['wall_s']:.0f} s, {last['env_steps']} env steps, "
      f"{last['critic_updates']} critic updates; warm-up {warmup:.0f} env steps/s; whole run {rate(zero, last, 'env_steps'):.1f} env steps/s, "
      f"{rate(zero, last, 'critic_updates'):.1f} updates/s; after warm-up {w:.1f} env steps/s, {u:.1f} updates/s")
PY
    done
done
export PYTHONPATH=$PWD/gymnasium/tests/python${PYTHONPATH:+:$PYTHONPATH}
for r in $(seq 1 "${BRIDGE_ROUNDS:-5}"); do
    echo "round $r:" \
        "bridge Hopper-v5 $("$selkd" bench env gymnasium:Hopper-v5 --steps "$steps" 2>&1 | tail -1) |" \
        "own $("$venv/bin/python" deploy/gym_env_steps.py Hopper-v5 "$steps") |" \
        "bridge SelkdEcho-v0 $("$selkd" bench env gymnasium:SelkdEcho-v0 --env-options 'import=["selkd_test_gym"]' --steps 50000 2>&1 | tail -1) |" \
        "own $("$venv/bin/python" -c 'import sys, runpy, selkd_test_gym; sys.argv = ["x", "SelkdEcho-v0", "50000"]; runpy.run_path("deploy/gym_env_steps.py", run_name="__main__")')"
done
