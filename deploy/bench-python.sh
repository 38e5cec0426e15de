#!/usr/bin/env bash
# The Python package's env speed, one sitting, interleaved task by task (this kind of machine is
# noisy: compare ratios, never one timing):
#   rust      `selkd bench env` (the Rust loop, no Python)
#   python    a Python loop over gymnasium.make("selkd/X-v0").step, with Gymnasium's wrappers
#   mujoco    the same loop over Gymnasium's own MuJoCo task (X-v5)
#   vec       gymnasium.make_vec("selkd/X-v0", num_envs=N): our vector env, stepped in Rust
#   vec-sync  Gymnasium's SyncVectorEnv over N of our envs
#   mj-sync   Gymnasium's SyncVectorEnv over N MuJoCo envs
# and the ratios python/rust, python/mujoco, vec/vec-sync, vec/mj-sync.
#   bash deploy/bench-python.sh [ROUNDS] [STEPS] [N]
# Needs deploy/python.sh's venv (it installs mujoco there on first use) and target/release/selkd.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
steps=${2:-10000}
n=${3:-8}
venv=${SELKD_PYTHON_VENV:-${SELKD_CACHE:-$HOME/.cache/selkd}/python-venv}
py="$venv/bin/python"
[ -x "$py" ] || { echo "bench-python: run bash deploy/python.sh first" >&2; exit 1; }
"$py" -c "import mujoco" 2>/dev/null || "$py" -m pip install --quiet mujoco==4.0.0
[ -x target/release/selkd ] || { echo "bench-python: build first: cargo build --release" >&2; exit 1; }
rate() { "$py" deploy/gym_env_steps.py "$@" 2>/dev/null | awk '{print $2}'; }
ratio() { awk -v a="$1" -v b="$2" 'BEGIN {printf "%.2f", a / b}'; }
lscpu | awk -F: '/Model name/ {gsub(/^ +/, "", $2); print "cpu: " $2}'
echo "threads of our vector env: one per core ($(nproc)), at most N = $n"
printf '%-3s %-12s %8s %8s %8s %8s %8s %8s | %6s %6s %6s %6s\n' \
    r task rust python mujoco vec vec-sync mj-sync py/rs py/mj vec/vs vec/mj
for r in $(seq 1 "$rounds"); do
    for pair in hopper:Hopper walker2d:Walker2d halfcheetah:HalfCheetah ant:Ant humanoid:Humanoid; do
        name=${pair%%:*} gym=${pair##*:}
        rust=$(target/release/selkd bench env "$name" --steps "$steps" | awk '/env steps/ {print $1}')
        python=$(rate "selkd/$gym-v0" "$steps")
        mujoco=$(rate "$gym-v5" "$steps")
        vec=$(rate "selkd/$gym-v0" "$steps" --vector "$n")
        vsync=$(rate "selkd/$gym-v0" "$steps" --vector "$n" --sync)
        mjsync=$(rate "$gym-v5" "$steps" --vector "$n" --sync)
        printf '%-3s %-12s %8s %8s %8s %8s %8s %8s | %6s %6s %6s %6s\n' "$r" "$name" \
            "$rust" "$python" "$mujoco" "$vec" "$vsync" "$mjsync" \
            "$(ratio "$python" "$rust")" "$(ratio "$python" "$mujoco")" \
            "$(ratio "$vec" "$vsync")" "$(ratio "$vec" "$mjsync")"
    done
done
