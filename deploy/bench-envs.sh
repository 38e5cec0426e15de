#!/usr/bin/env bash
# Env steps/s of our locomotion tasks against Gymnasium's MuJoCo versions, interleaved task by
# task in one sitting (this kind of machine is noisy: compare ratios, never one timing).
#   bash deploy/bench-envs.sh [ROUNDS] [STEPS]
# Needs target/release/selkd; makes a throwaway venv with gymnasium and mujoco on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
steps=${2:-10000}
venv=${SELKD_MUJOCO_VENV:-$HOME/.cache/selkd/mujoco-venv}
# gymnasium[mujoco]: Gymnasium 1.4's MuJoCo envs also import imageio, which plain `gymnasium
# mujoco` does not bring (the first MuJoCo step then fails, and with it the sitting).
if ! "$venv/bin/python" -c "import gymnasium, mujoco, imageio" 2>/dev/null; then
    echo "bench-envs: making $venv (gymnasium[mujoco])" >&2
    [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet "gymnasium[mujoco]"
fi
[ -x target/release/selkd ] || { echo "bench-envs: build first: cargo build --release" >&2; exit 1; }
printf '%-6s %-12s %10s %10s %6s\n' round task ours mujoco ratio
for r in $(seq 1 "$rounds"); do
    for pair in hopper:Hopper-v5 walker2d:Walker2d-v5 halfcheetah:HalfCheetah-v5 ant:Ant-v5 humanoid:Humanoid-v5; do
        ours=$(target/release/selkd bench env "${pair%%:*}" --steps "$steps" | awk '/env steps/ {print $1}')
        theirs=$("$venv/bin/python" deploy/gym_env_steps.py "${pair##*:}" "$steps" 2>/dev/null | awk '{print $2}')
        printf '%-6s %-12s %10s %10s %6s\n' "$r" "${pair%%:*}" "$ours" "$theirs" \
            "$(awk -v a="$ours" -v b="$theirs" 'BEGIN {printf "%.2f", a / b}')"
    done
done
