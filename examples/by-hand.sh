#!/usr/bin/env bash
# A SELKD run started by hand: one learner and two actor-workers, the processes `selkd train`
# starts for you (deploy/src/train.rs, `supervise` and `spawn_worker`). Run this script, or type
# its three commands in three terminals, from the repository root after
# `cargo build --release --workspace`:
#
#   terminal 1:  target/release/learner --config configs/quick.toml --set algo.actors=2 \
#                    --run-dir runs/by-hand --run-id by-hand
#   terminal 2:  target/release/actor-worker --run-id by-hand --worker 0 --env pendulum
#   terminal 3:  target/release/actor-worker --run-id by-hand --worker 1 --env pendulum
#
# The run id names the run's iceoryx2 services (`selkd/<run-id>/...`, protocol/src/lib.rs), so
# it must be the same in all three and unique on the host. A worker checks the learner's
# announced run against its own `--env` and `--env-options` (a mismatch exits 2), takes its
# actor's current weights and its place in the rollout, and steps until the learner says stop;
# workers started before the learner wait for it (`--connect-timeout`, 60 s). `--worker I` runs
# actor I, so K actors need K workers, 0..K-1: here `algo.actors=2`, as quick.toml has 3.
# A config with `[env_options]` needs them on each worker as JSON: `--env-options '{"g": 9.81}'`.
#
# The learner prints a `PROGRESS {json}` line a second (`selkd train` turns these into its
# progress line) and ends at the config's budget, 12 000 env steps for quick.toml (about a
# minute): it writes runs/by-hand/metrics.csv and checkpoints/final, the workers exit 0 when it
# tells them to stop, and `selkd eval runs/by-hand` scores the result. Ctrl-C in terminal 1
# stops the run with a checkpoint; restart a worker that died with the same command (it rejoins
# where the learner's record of its rollout ends). Unlike `selkd train`, nothing here restarts a
# worker, writes the run's config.toml or logs/, or locks the run directory; nor does it refuse
# a directory that holds a run: give each run its own RUN_DIR (the learner appends to an existing
# metrics.csv), or continue one with `--resume RUN_DIR/checkpoints/final` on the learner.
#
# Settings (environment): BIN (target/release), CONFIG (configs/quick.toml), RUN_DIR
# (runs/by-hand), RUN_ID (by-hand), ENV (pendulum: the config's run.env); arguments go to the
# learner, e.g. `examples/by-hand.sh --set run.total_env_steps=3000`. tests/tests/examples.rs
# runs this script on a tiny config.
set -euo pipefail
BIN=${BIN:-target/release}
CONFIG=${CONFIG:-configs/quick.toml}
RUN_DIR=${RUN_DIR:-runs/by-hand}
RUN_ID=${RUN_ID:-by-hand}
ENV=${ENV:-pendulum}

# Terminal 1: the learner.
"$BIN/learner" --config "$CONFIG" --set algo.actors=2 --run-dir "$RUN_DIR" --run-id "$RUN_ID" "$@" &
learner=$!
# Terminals 2 and 3: one worker per actor.
"$BIN/actor-worker" --run-id "$RUN_ID" --worker 0 --env "$ENV" &
worker0=$!
"$BIN/actor-worker" --run-id "$RUN_ID" --worker 1 --env "$ENV" &
worker1=$!
trap 'kill -TERM $learner $worker0 $worker1 2>/dev/null || true' INT TERM

status=0
wait $learner || status=$?
wait $worker0 || status=$?
wait $worker1 || status=$?
exit $status
