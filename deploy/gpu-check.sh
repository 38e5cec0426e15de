#!/usr/bin/env bash
# The learner's GPU measurement (`run.device = "cuda"`) as one command on a machine with an NVIDIA
# GPU whose python3 holds PyTorch 2.11 with CUDA, where nothing is built: the binaries travel,
# stripped, in .gpu/ (about 30 MB), and link the libtorch of that machine's PyTorch.
#   bash deploy/gpu-check.sh pack        # here: release build; stripped binaries into .gpu/
#   bash deploy/gpu-check.sh run [DIR]   # there, from the clone's root with .gpu/ beside it
# `run` prints the GPU, then the benchmark against the peer on the GPU (deploy/bench-learner.sh:
# K = 1 and K = 5, fp32 and bf16, two rounds), then trains configs/paper.toml on hopper for
# TRAIN_SECONDS (default 150) with run.device = cuda and prints its update rate over the last
# 60 s. Everything goes to DIR (default $OUT, else gpu-check/): gpu-check.txt, and the training's
# progress.jsonl and metrics.csv. DEVICE=cpu runs the same steps on the CPU, to try the script on a
# machine without a GPU; PYTHON names another Python with torch.
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
pack)
    cargo build --release --workspace --locked
    mkdir -p .gpu
    for b in selkd learner actor-worker; do strip -o ".gpu/$b" "target/release/$b"; done
    echo "gpu-check: .gpu/ holds $(du -sh .gpu | cut -f1); carry it and run: bash deploy/gpu-check.sh run" >&2
    ;;
run)
    out=${2:-${OUT:-gpu-check}}
    device=${DEVICE:-cuda}
    python=${PYTHON:-python3}
    seconds=${TRAIN_SECONDS:-150}
    for b in selkd learner actor-worker; do
        [ -e ".gpu/$b" ] || { echo "gpu-check: .gpu/$b is missing: run bash deploy/gpu-check.sh pack first, and carry .gpu" >&2; exit 1; }
    done
    mkdir -p "$out"
    # The binaries' baked-in libtorch path is this build machine's; that machine's wheel stands in.
    torch_lib=$("$python" -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))') \
        || { echo "gpu-check: $python cannot import torch; set PYTHON" >&2; exit 1; }
    export LD_LIBRARY_PATH="$torch_lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    run_dir=$(mktemp -d)/train
    {
        echo "== the machine"
        date -u
        if [ "$device" != cpu ]; then nvidia-smi || true; fi
        "$python" -c 'import torch; print("torch", torch.__version__, "cuda", torch.version.cuda, "devices", torch.cuda.device_count())'
        echo "== the benchmark against the peer, on $device"
        SELKD=.gpu/selkd DEVICE=$device PYTHON=$python THREADS=1 \
            bash deploy/bench-learner.sh 2
        echo "== configs/paper.toml on hopper, run.device = $device, $seconds s"
        # SIGINT is a clean stop: the run checkpoints and the workers exit.
        timeout -s INT "$seconds" .gpu/selkd train --config configs/paper.toml --set run.env=hopper \
            --set "run.device=$device" --set eval.episodes=2 --run-dir "$run_dir" || true
        cp "$run_dir/logs/progress.jsonl" "$run_dir/metrics.csv" "$out/" 2>/dev/null || true
        "$python" - "$run_dir/logs/progress.jsonl" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
last = rows[-1]
early = [r for r in rows if r["wall_s"] <= last["wall_s"] - 60]
if not early or last["critic_updates"] == early[-1]["critic_updates"]:
    sys.exit(f"training: no updates over the last 60 s ({len(rows)} progress rows)")
a = early[-1]
rate = (last["critic_updates"] - a["critic_updates"]) / (last["wall_s"] - a["wall_s"])
print(f"training: {rate:.1f} critic updates/s over the last {last['wall_s'] - a['wall_s']:.0f} s "
      f"({last['critic_updates']} updates, {last['env_steps']} env steps in {last['wall_s']:.0f} s)")
PY
    } 2>&1 | tee "$out/gpu-check.txt"
    ;;
*)
    echo "gpu-check: say pack (here) or run (on the GPU machine); see the top of deploy/gpu-check.sh" >&2
    exit 1
    ;;
esac
