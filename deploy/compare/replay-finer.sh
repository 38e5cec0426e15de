#!/usr/bin/env bash
# Issue 32's learned check on any finished run of one of our rapier tasks: its ranked actor
# replayed on the same EPISODES fresh episodes (seeds SEED..SEED+EPISODES-1) at the physics it
# trained on and integrated 10x finer (10x the rapier steps per control step; the same control
# step, solver iterations, prediction distance and limit springs). The physics come from the
# run's own record (`state.json`, `env`: the last stretch), so the replay is of the setting the
# run trained at whatever the build's defaults are now (the robots' physics keys: rapier
# steps, solver passes and relax iterations, prediction distance, limit springs and their
# integration; a run's other `[env_options]` are not passed). Writes OUT/coarseEPISODES.json and
# OUT/fineEPISODES.json (`selkd eval --json`) and prints one table row: mean return and episode
# length at each, the gap |coarse - fine| / |fine| and the gap's standard error (the two
# replays' episodes are independent; a gap within about two of them may be the episodes'
# spread, not the integration). Not a test: a measurement to run by hand
# (docs/results/fidelity.md).
#   bash deploy/compare/replay-finer.sh RUN OUT [EPISODES] [SEED]
#   bash deploy/compare/replay-finer.sh experiments/runs/evidence-rapier/sac/hopper/seed-1 /tmp/r 50 1000
# FINE_STEPS=F FINE_PASSES=P (defaults 10 and 1) make the reference F x the rapier steps and P x the
# solver passes: 10 x the steps alone is not converged in solver passes for every policy
# (docs/results/fidelity.md, "The walker at 100k, and the second axis"); FINE_STEPS=10
# FINE_PASSES=16 from 8 x 1 is the 80 x 16 used there. The reference's files are then named
# fineEPISODES-sFxP.json.
set -euo pipefail
cd "$(dirname "$0")/../.."
run=${1:?usage: replay-finer.sh RUN OUT [EPISODES] [SEED]}
out=${2:?usage: replay-finer.sh RUN OUT [EPISODES] [SEED]}
episodes=${3:-50}
seed=${4:-1000}
selkd=${SELKD_BIN:-target/release/selkd}
[ -x "$selkd" ] || { echo "replay-finer: build first: cargo build --release" >&2; exit 1; }
state="$run/checkpoints/final/state.json"
[ -f "$state" ] || { echo "replay-finer: $run has no final checkpoint ($state): replay a finished run's directory, not a published one (it has no weights)" >&2; exit 1; }
# The physics of the run's last stretch, as [env_options] lines, with its rapier steps and solver
# passes multiplied by the two arguments (1 1: the setting it trained at).
physics() {
    python3 - "$state" "$1" "$2" <<'EOF'
import json, sys
env = json.load(open(sys.argv[1])).get("env") or []
if not env or not env[-1]["record"].get("physics"):
    sys.exit("replay-finer: the run's state.json records no rapier physics (a run from before "
             "the env records, or an env without rapier settings)")
p = env[-1]["record"]["physics"]
steps, passes = (int(x) for x in sys.argv[2:4])
print(f"substeps = {p['substeps'] * steps}")
print(f"solver_iterations = {p['solver_iterations'] * passes}")
for key in ("prediction_distance", "limit_frequency"):
    print(f"{key} = {p[key]}")
# Records older than these keys were made with their first defaults.
print(f"implicit_limits = {str(p.get('implicit_limits', False)).lower()}")
print(f"stabilization_iterations = {p.get('stabilization_iterations', 1)}")
print(f"pgs_iterations = {p.get('pgs_iterations', 1)}")
EOF
}
fine_steps=${FINE_STEPS:-10}
fine_passes=${FINE_PASSES:-1}
coarse=$(physics 1 1)
fine=$(physics "$fine_steps" "$fine_passes")
# The plain 10x-steps reference keeps its old name; another says which it is.
ref=""
{ [ "$fine_steps" = 10 ] && [ "$fine_passes" = 1 ]; } || ref="-s${fine_steps}x$fine_passes"
mkdir -p "$out"
# One replay; `selkd eval`'s stderr (its note that the env differs from the training one, which
# is the point here) is shown only if it fails.
replay() {
    "$selkd" eval "$run" --episodes "$episodes" --seed "$seed" --json --env-options "$1" \
        > "$2" 2> "$out/eval.log" \
        || { echo "replay-finer: selkd eval of $run failed:" >&2; cat "$out/eval.log" >&2; exit 1; }
}
replay "$coarse" "$out/coarse$episodes.json"
replay "$fine" "$out/fine$episodes$ref.json"
rm -f "$out/eval.log"
python3 deploy/compare/replay_gap.py row "$out/coarse$episodes.json" "$out/fine$episodes$ref.json" "$run"
