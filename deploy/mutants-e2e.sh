#!/usr/bin/env bash
# The end-to-end mutation reading of the process code (docs/mutants.md, "The process code against
# the end-to-end tests"): cargo-mutants lists each file's mutants, deploy/mutants_e2e.py applies
# them one at a time in this checkout, rebuilds the release binaries and runs the stages below.
# Results go to docs/mutants/<crate>-<file>.csv (resumable: a mutant already there is skipped),
# so a reading continued on another machine picks up where the committed data stops.
#
#   bash deploy/mutants-e2e.sh                                  # every file below (many hours)
#   bash deploy/mutants-e2e.sh actor-worker/src/link.rs         # one file
#   NO_BASELINE=1 bash deploy/mutants-e2e.sh learner/src/service.rs  # resumed: skip the stages'
#                                   # first run on the unmutated source (its kept times still
#                                   # set the stages' limits: 5 × each, 120 s at least)
#
# It mutates files in place and refuses to start with uncommitted changes in them; don't edit
# the checkout while it runs. Each caught mutant takes about a minute on 2 cores, one that
# reaches the last stage four to five; one that hangs a stage runs to 5 × the stage's baseline
# time (--timeout 900 and the stage-1 limit below when there is none).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash deploy/setup.sh

tool_bin=$(bash deploy/cargo-mutants.sh)
# Incremental compilation of the workspace's own crates, as deploy/mutants.sh: a service.rs
# mutant's rebuild of the learner's tests then takes 17 s instead of 166 (one loaded sitting,
# twenty-first session); the first run rebuilds the workspace crates once, and so does the next
# build without it, so keep the reading in a checkout of its own (a git worktree).
export CARGO_PROFILE_RELEASE_INCREMENTAL=true
export PATH="$tool_bin:$PATH"

files=("$@")
[ ${#files[@]} -gt 0 ] || files=(actor-worker/src/rollout.rs actor-worker/src/link.rs
  actor-worker/src/main.rs protocol/src/lib.rs learner/src/service.rs learner/src/workers.rs)

for f in "${files[@]}"; do
  # The package's own tests run first: they build in a minute or two and run in seconds, where
  # an end-to-end stage runs for minutes, so only the mutants they miss reach those. (Until the
  # eighth session's link.rs reading only the protocol's did; the CSVs of rollout.rs and the
  # protocol number their stages as docs/mutants.md says.)
  e2e="cargo test --release -p selkd-tests"
  case "$f" in
    actor-worker/*) pkg=selkd-actor-worker; unit_timeout=120; build="cargo build --release -p selkd-actor-worker" ;;
    # The learner's unit tests run in about 25 s (a minute on a loaded machine): 300 s calls a
    # hang a timeout without letting a runaway mutant fill the disk first.
    learner/*) pkg=selkd-learner; unit_timeout=300; build="cargo build --release -p selkd-learner --bin learner" ;;
    protocol/*) pkg=selkd-protocol; unit_timeout=120
      # Every binary depends on the protocol: rebuilt only for the mutants its tests miss.
      build="cargo build --release --workspace --bins" ;;
    *) echo "mutants-e2e: $f is not in actor-worker, learner or protocol" >&2; exit 2 ;;
  esac
  name=$(echo "$f" | sed 's#/src/#-#; s#\.rs$##; s#/#-#g')
  list="target/mutants-e2e/$name.json"
  mkdir -p target/mutants-e2e docs/mutants
  # --package: listing the whole workspace runs out of memory. `Vec::leak`: cargo-mutants writes
  # every combination of defaults for a function returning a tuple of slices (768 for one).
  cargo mutants --in-place --list --json --diff --package "$pkg" --file "$f" \
    --exclude-re 'Vec::leak' > "$list"
  # Only the package's test binary is built before stage 1, so that stage 1 only runs it (in
  # seconds for the worker and the protocol) and a mutant that hangs it is called a timeout after
  # $unit_timeout s, not 15 minutes. The binaries the end-to-end stages start are built by the
  # first of those stages: most mutants never get there (learner/src/service.rs: a mutant
  # caught in stage 1 took 110–176 s with this against 166–217 s before, a loaded machine).
  e2e="$build && $e2e"
  python3 deploy/mutants_e2e.py "$list" "docs/mutants/$name.csv" ${NO_BASELINE:+--no-baseline} \
    --build "cargo test --release -p $pkg --no-run" --timeout 900 \
    --stage-timeout "$unit_timeout" \
    --stage "cargo test --release -p $pkg" \
    --stage "$e2e --test data_path" \
    --stage "$e2e --test faults --test recovery --test examples -- --test-threads 1" \
    --stage "$e2e --test gymnasium -- an_exception_in_step" \
    --stage "$e2e --test hardening --test tensorboard -- --test-threads 1"
done
