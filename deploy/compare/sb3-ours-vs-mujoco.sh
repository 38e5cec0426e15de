#!/usr/bin/env bash
# Issue 32's plausibility check (goal 2): Stable-Baselines3's SAC, unchanged but for
# learning_starts = 5000, on one of our rapier tasks (through the selkd Python package) and on
# Gymnasium's MuJoCo v5 task of the same name, SEEDS seeds each, evaluated every EVERY env steps
# on 10 deterministic episodes. The mean returns' ratio (ours / MuJoCo) at 30k and at STEPS
# should lie in [0.5, 2]. Writes OUT/TASK/{ours,mujoco}/seed-N.{csv,seconds,log} and
# OUT/table.md (every task under OUT, with how many seeds each side has so far), and prints the
# table. Not a test: a measurement to run by hand (docs/results/fidelity.md). OUT defaults to
# docs/results/sb3-ours-vs-mujoco, where each finished run is committed as data: the
# measurement takes ~22 core-hours, more than one machine's session, and continues on the next.
#   bash deploy/compare/sb3-ours-vs-mujoco.sh [TASK] [SEEDS] [STEPS] [OUT]
#   JOBS=2 bash deploy/compare/sb3-ours-vs-mujoco.sh halfcheetah 3 100000
# TASK: hopper, walker2d, halfcheetah, ant or humanoid. Resumable: a run whose seed-N.csv exists
# is skipped (SB3 cannot resume midway, so an interrupted run starts again). JOBS runs at a time
# (default 1), one thread each; EVERY defaults to 10000. TABLE_ONLY=1 runs nothing and writes
# the table from the runs there are. Needs the venv deploy/python.sh makes.
set -euo pipefail
cd "$(dirname "$0")/../.."
task=${1:-halfcheetah}
seeds=${2:-3}
steps=${3:-100000}
root_out=${4:-docs/results/sb3-ours-vs-mujoco}
out=$root_out/$task
every=${EVERY:-10000}
jobs=${JOBS:-1}
# The probes' switches of sb3_sac.py change the task: never inherited by this measurement.
unset SB3_ENV_OPTIONS SB3_END_FLIPPED
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
if [ -z "${TABLE_ONLY:-}" ]; then
    for s in $(seq 1 "$seeds"); do
        for engine in ours mujoco; do
            [ -f "$out/$engine/seed-$s.csv" ] || echo "$engine $s"
        done
    done | xargs -r -P "$jobs" -L 1 bash -c 'one $0 $1'
fi
python3 - "$root_out" "$steps" "$seeds" docs/results/published/gym-mujoco-v4.csv <<'EOF' | tee "$root_out/table.md"
import csv, glob, os, statistics, sys
root, steps, seeds, published = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
# Published SAC on Gym's v4 task (SimbaV2's curves, deploy/published_baselines.py): whether the
# MuJoCo side's seeds are typical of SAC there. A reference beside the ratio, not part of it.
sac = {(r["task"].lower(), int(r["budget_env_steps"])): r for r in csv.DictReader(open(published))
       if r["method"] == "SAC"}
def published_cell(task, at):
    r = sac.get((task, at))
    if r is None:
        return "–"
    return f"{float(r['mean']):.0f} ± {float(r['std']):.0f} ({r['seeds']} seeds, {int(r['env_step']) // 1000}k)"
def evaluations(task, engine, at):
    """Each seed's (mean return, mean length or None) at `at` env steps, by seed. Runs before
    the twenty-fifth session wrote no length."""
    got = {}
    for f in sorted(glob.glob(f"{root}/{task}/{engine}/seed-*.csv")):
        for line in open(f):
            seed, step, ret, *length = line.strip().split(",")
            if int(step) == at:
                got[int(seed)] = (float(ret), float(length[0]) if length else None)
    return [got[s] for s in sorted(got)]
def lengths_cell(ours, mujoco):
    """Mean episode length on each side, where every seed there has one."""
    def side(v):
        return f"{statistics.mean(v):.0f}" if v and None not in v else "–"
    return f"{side([l for _, l in ours])} / {side([l for _, l in mujoco])}"
def cell(v):
    if not v:
        return "–"
    sd = f" ± {statistics.stdev(v):.0f}" if len(v) > 1 else ""
    return f"{statistics.mean(v):.0f}{sd} ({', '.join(f'{x:.0f}' for x in v)})"
print("SB3's SAC (its defaults, learning_starts = 5000) on our rapier task and on Gymnasium's")
print("MuJoCo v5 task of the same name: mean return of 10 deterministic episodes per seed, then")
print("mean ± sample std over seeds (each seed's in brackets). Goal: ratio in [0.5, 2].")
print(f"Seeds wanted per side: {seeds}; a row with fewer is partial. Beside them, SAC's published")
print("curves on Gym's v4 task (SimbaV2's repository, results/baseline/sac.csv; mean ± std over")
print("its seeds at the evaluation nearest the budget), to show whether the MuJoCo side is typical.")
print("Episode length: the mean over seeds of each evaluation's mean, where every seed's run")
print("recorded it (1 000 at most; the halfcheetah's always; a hopper, walker or ant that only")
print("stands earns about 1 a step, a humanoid 5, so return minus that is the gait's share).")
print()
print("| task | env steps | ours (rapier) | MuJoCo v5 | seeds (ours, MuJoCo) | ratio | in [0.5, 2] | episode length (ours / MuJoCo) | published SAC (v4) |")
print("|---|---|---|---|---|---|---|---|---|")
for task in ["hopper", "walker2d", "halfcheetah", "ant", "humanoid"]:
    if not os.path.isdir(f"{root}/{task}"):
        continue
    for at in sorted({min(30000, steps), steps}):
        ours, mujoco = evaluations(task, "ours", at), evaluations(task, "mujoco", at)
        a, b = [r for r, _ in ours], [r for r, _ in mujoco]
        ratio, ok = "–", "–"
        if a and b and statistics.mean(b):
            r = statistics.mean(a) / statistics.mean(b)
            ratio, ok = f"{r:.2f}", ("yes" if 0.5 <= r <= 2 else "**no**")
            if min(len(a), len(b)) < seeds:
                ok += " (partial)"
        print(f"| {task} | {at} | {cell(a)} | {cell(b)} | {len(a)}, {len(b)} | {ratio} | {ok} | {lengths_cell(ours, mujoco)} | {published_cell(task, at)} |")
EOF
