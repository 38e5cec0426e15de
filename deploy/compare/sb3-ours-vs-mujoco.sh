#!/usr/bin/env bash
# Issue 32's plausibility check (goal 2): Stable-Baselines3's SAC, unchanged but for
# learning_starts = 5000, on one of our rapier tasks (through the selkd Python package) and on
# Gymnasium's MuJoCo v5 task of the same name, SEEDS seeds each, evaluated every EVERY env steps
# on 10 deterministic episodes. The mean returns' ratio (ours / MuJoCo) at 30k and at STEPS
# should lie in [0.5, 2]. Writes OUT/TASK/{ours,mujoco}/seed-N.csv and OUT/TASK/table.md, and
# prints the table. Not a test: a measurement to run by hand (docs/results/fidelity.md).
#   bash deploy/compare/sb3-ours-vs-mujoco.sh [TASK] [SEEDS] [STEPS] [OUT]
#   JOBS=2 bash deploy/compare/sb3-ours-vs-mujoco.sh halfcheetah 3 100000 /work/fidelity-runs
# TASK: hopper, walker2d, halfcheetah, ant or humanoid. Resumable: a run whose seed-N.csv exists
# is skipped (SB3 cannot resume midway, so an interrupted run starts again). JOBS runs at a time
# (default 1), one thread each; EVERY defaults to 10000. Needs the venv deploy/python.sh makes.
set -euo pipefail
cd "$(dirname "$0")/../.."
task=${1:-halfcheetah}
seeds=${2:-3}
steps=${3:-100000}
out=${4:-runs/sb3-ours-vs-mujoco}/$task
every=${EVERY:-10000}
jobs=${JOBS:-1}
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
venv=${SELKD_PYTHON_VENV:-$cache/python-venv}
case "$task" in
    hopper) name=Hopper ;;
    walker2d) name=Walker2d ;;
    halfcheetah) name=HalfCheetah ;;
    ant) name=Ant ;;
    humanoid) name=Humanoid ;;
    *) echo "sb3-ours-vs-mujoco: TASK is one of hopper, walker2d, halfcheetah, ant, humanoid (got $task)" >&2; exit 2 ;;
esac
"$venv/bin/python" -c "import stable_baselines3, selkd" 2>/dev/null \
    || { echo "sb3-ours-vs-mujoco: no Stable-Baselines3 or selkd package in $venv; run bash deploy/python.sh first" >&2; exit 1; }
mkdir -p "$out/ours" "$out/mujoco"
one() {
    # xargs' bash does not inherit pipefail: without it a failed run would count as done.
    set -o pipefail
    local engine=$1 s=$2 id t0=$SECONDS
    id=$name-v5
    [ "$engine" = ours ] && id=selkd/$name-v0
    LEARNING_STARTS=5000 "$venv/bin/python" deploy/compare/sb3_sac.py "$id" "$s" "$steps" "$every" 10 \
        2> "$out/$engine/seed-$s.log" > "$out/$engine/seed-$s.csv.partial" \
        || { echo "sb3-ours-vs-mujoco: $engine seed $s failed; see $out/$engine/seed-$s.log" >&2; return 1; }
    echo $((SECONDS - t0)) > "$out/$engine/seed-$s.seconds"
    mv "$out/$engine/seed-$s.csv.partial" "$out/$engine/seed-$s.csv"
}
export -f one; export out steps every venv name
for s in $(seq 1 "$seeds"); do
    for engine in ours mujoco; do
        [ -f "$out/$engine/seed-$s.csv" ] || echo "$engine $s"
    done
done | xargs -r -P "$jobs" -L 1 bash -c 'one $0 $1'
python3 - "$out" "$steps" <<'EOF' | tee "$out/table.md"
import glob, statistics, sys
out, steps = sys.argv[1], int(sys.argv[2])
def returns(engine, at):
    got = {}
    for f in sorted(glob.glob(f"{out}/{engine}/seed-*.csv")):
        for line in open(f):
            seed, step, ret = line.strip().split(",")
            if int(step) == at:
                got[int(seed)] = float(ret)
    return got
def cell(v):
    if not v:
        return "–"
    sd = f" ± {statistics.stdev(v):.0f}" if len(v) > 1 else ""
    return f"{statistics.mean(v):.0f}{sd} ({', '.join(f'{x:.0f}' for x in v)})"
print("| env steps | ours (rapier), SB3 SAC | MuJoCo v5, SB3 SAC | ratio |")
print("|---|---|---|---|")
for at in sorted({min(30000, steps), steps}):
    a, b = returns("ours", at), returns("mujoco", at)
    a, b = [a[s] for s in sorted(a)], [b[s] for s in sorted(b)]
    ratio = f"{statistics.mean(a) / statistics.mean(b):.2f}" if a and b and statistics.mean(b) else "–"
    print(f"| {at} | {cell(a)} | {cell(b)} | {ratio} |")
EOF
