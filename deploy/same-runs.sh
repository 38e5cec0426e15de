#!/usr/bin/env bash
# Proof that a change kept behaviour: every shipped config (configs/*.toml, configs/baselines/*.toml)
# trained briefly on Pendulum in sync mode by two builds must give byte-identical runs: metrics.csv
# without its wall-clock columns (wall_s, updates_per_s, env_steps_per_s), and the final checkpoint's
# model.safetensors, replay.safetensors and state.json (without wall_seconds; a key only the new
# build writes, such as a new config key at its default, is named, not counted as a difference).
#
#   bash deploy/same-runs.sh build REF DIR     # builds git REF's selkd, learner, actor-worker into DIR
#   bash deploy/same-runs.sh compare OLD NEW   # OLD, NEW: directories holding those three binaries
#
# e.g. before landing a refactor:
#   bash deploy/same-runs.sh build main /tmp/old && cargo build --release --locked &&
#   bash deploy/same-runs.sh compare /tmp/old target/release
# Each config runs on Pendulum (one with env_options on its own env) for 1 500 env steps (500 of warm-up) with 32 × 32 networks and one thread; its
# sizes K, N, M, G and its method's settings are its own. Exits 1 naming every config that differs.
# SAME_RUNS_DIR keeps the runs (default: a temporary directory, removed after).
set -euo pipefail
cd "$(dirname "$0")/.."

die() { echo "same-runs: $*" >&2; exit 2; }

case "${1:-}" in
build)
    ref=${2:?usage: same-runs.sh build REF DIR}
    dest=${3:?usage: same-runs.sh build REF DIR}
    rev=$(git rev-parse --verify "$ref^{commit}") || die "$ref is not a commit"
    src=$(mktemp -d)/src
    git worktree add --detach -q "$src" "$rev"
    trap 'git worktree remove --force "$src"' EXIT
    # Its own target directory, kept between calls: a second build of a nearby commit is incremental.
    CARGO_TARGET_DIR="$PWD/target/same-runs" cargo build --release --locked --manifest-path "$src/Cargo.toml" \
        -p selkd-deploy -p selkd-learner -p selkd-actor-worker
    mkdir -p "$dest"
    for b in selkd learner actor-worker; do cp "target/same-runs/release/$b" "$dest/"; done
    echo "same-runs: $rev's binaries are in $dest"
    ;;
compare)
    old=${2:?usage: same-runs.sh compare OLD NEW}
    new=${3:?usage: same-runs.sh compare OLD NEW}
    for d in "$old" "$new"; do
        for b in selkd learner actor-worker; do
            [ -x "$d/$b" ] || die "$d/$b is missing (build it: same-runs.sh build REF $d)"
        done
    done
    work=${SAME_RUNS_DIR:-$(mktemp -d)}
    [ -n "${SAME_RUNS_DIR:-}" ] || trap 'rm -rf "$work"' EXIT
    differ=()
    for config in configs/*.toml configs/baselines/*.toml; do
        name=$(basename "${config%.toml}")
        [ "$(dirname "$config")" = configs ] || name="baselines-$name"
        # A config with env_options is made for its env (fpc-assembly): it keeps it.
        env=(--set run.env=pendulum)
        grep -q '^\[env_options' "$config" && env=()
        for side in old new; do
            bin=$old; [ $side = new ] && bin=$new
            rm -rf "${work:?}/$name-$side"
            "$bin/selkd" train --config "$config" --run-dir "$work/$name-$side" \
                "${env[@]}" --set run.mode=sync --set run.device=cpu --set run.threads=1 \
                --set run.total_env_steps=1500 --set algo.warmup_steps=500 \
                --set 'algo.hidden=[32,32]' --set algo.batch_size=64 --set run.checkpoint_every=1000 \
                --set run.checkpoint_replay=true --set eval.episodes=1 --set eval.epoch_env_steps=500 \
                >"$work/$name-$side.log" 2>&1 || die "$config with $bin failed: see $work/$name-$side.log (SAME_RUNS_DIR keeps it)"
        done
        if python3 - "$work/$name-old" "$work/$name-new" <<'PY'
import csv, json, sys
from pathlib import Path

def metrics(d):
    rows = list(csv.reader(open(Path(d) / "metrics.csv")))
    keep = [i for i, h in enumerate(rows[0]) if h not in ("wall_s", "updates_per_s", "env_steps_per_s")]
    return [[r[i] for i in keep] for r in rows]

def checkpoint(d):
    c = Path(d) / "checkpoints" / "final"
    state = json.loads((c / "state.json").read_text())
    state.pop("wall_seconds", None)
    return state, (c / "model.safetensors").read_bytes(), (c / "replay.safetensors").read_bytes()

def added_keys(old, new, path=""):
    """Keys only the new state.json has (a config key the new build added, at its default), or
    None where the two differ otherwise."""
    if isinstance(old, dict) and isinstance(new, dict):
        added = [path + k for k in new if k not in old]
        if any(k not in new for k in old):
            return None
        for k in old:
            sub = added_keys(old[k], new[k], path + k + ".")
            if sub is None:
                return None
            added += sub
        return added
    return [] if old == new else None

a, b = sys.argv[1:3]
problems = []
if metrics(a) != metrics(b):
    problems.append("metrics.csv")
(sa, *files_a), (sb, *files_b) = checkpoint(a), checkpoint(b)
added = added_keys(sa, sb)
if added is None:
    problems.append("state.json")
elif added:
    print("note: state.json has keys the old build lacks: " + ", ".join(added), end="; ")
for what, x, y in zip(("model.safetensors", "replay.safetensors"), files_a, files_b):
    if x != y:
        problems.append(what)
if problems:
    print("differ: " + ", ".join(problems))
    sys.exit(1)
PY
        then
            echo "same-runs: $config: identical"
        else
            differ+=("$config")
        fi
    done
    if [ ${#differ[@]} -gt 0 ]; then
        echo "same-runs: ${#differ[@]} config(s) differ: ${differ[*]}" >&2
        exit 1
    fi
    echo "same-runs: every shipped config gives the same run with both builds"
    ;;
*)
    die "usage: same-runs.sh build REF DIR | compare OLD NEW"
    ;;
esac
