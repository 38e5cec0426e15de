#!/usr/bin/env bash
# Mutation testing of the learner's algorithm code with cargo-mutants: each mutant (an operator
# flipped, a function body replaced by a default, ...) is built and `cargo test -p selkd-learner`
# run against it; a mutant the tests still pass is a gap in the tests (or an equivalent change).
# Results and the survivors' list go to target/mutants/mutants.out (ignored by git; MUTANTS_OUT
# for another folder); docs/mutants.md
# records the last full reading.
#
#   deploy/mutants.sh                          # every file below (hours on 2 cores)
#   deploy/mutants.sh learner/src/targets.rs   # just these files
#   deploy/mutants.sh learner/src/selkd.rs --re update_actors    # then cargo-mutants flags, as given
#
# It mutates the files in place (cargo-mutants puts each back after its mutant, and on Ctrl-C),
# so it reuses this clone's release build instead of building a copy from scratch; it refuses to
# start with uncommitted changes under learner/src. Don't edit learner/src while it runs.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash deploy/setup.sh

tool_bin=$(bash deploy/cargo-mutants.sh)

if ! git diff --quiet HEAD -- learner/src; then
  echo "mutants: learner/src has uncommitted changes; commit or stash them first (mutants run in place)" >&2
  exit 1
fi

# Arguments: files, then (from the first one starting with -) cargo-mutants flags, passed as given.
files=()
while [ $# -gt 0 ] && [ "${1#-}" = "$1" ]; do files+=("$1"); shift; done
if [ ${#files[@]} -eq 0 ]; then
  files=(selkd targets distillation squashed_gaussian optim replay ranking rate_limit ensemble)
  files=("${files[@]/#/learner/src/}")
  files=("${files[@]/%/.rs}")
fi
args=()
for f in "${files[@]}"; do args+=(--file "$f"); done

# One job at a time (--in-place allows no more; --jobs 1 in effect); the release profile, as the tests run, with incremental compilation of the
# workspace's own crates: a mutant's rebuild then takes about 30 s instead of 90 (the first run
# rebuilds the workspace crates once, and so does the next build without it). A mutant whose
# tests run past the timeout (an endless loop) counts as caught by timeout. MUTANTS_OUT picks
# another results folder (to keep several readings).
export CARGO_PROFILE_RELEASE_INCREMENTAL=true
out=${MUTANTS_OUT:-target/mutants}
mkdir -p "$out"
# shellcheck disable=SC2086 # MUTANTS_ARGS is a list of flags
PATH="$tool_bin:$PATH" cargo mutants --package selkd-learner --profile release \
  --in-place --timeout 300 --build-timeout 1200 --output "$out" \
  "${args[@]}" ${MUTANTS_ARGS:-} "$@"
