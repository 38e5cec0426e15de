#!/usr/bin/env python3
"""Mutation testing of the process code against the end-to-end tests.

cargo-mutants builds and tests one package; the processes' code (the actor-worker, the learner's
service, the protocol) is exercised by `tests/`, which start the release binaries of other
packages, which `cargo test -p selkd-tests` does not rebuild. So this applies cargo-mutants'
own mutants (its `--list --json --diff` output) one at a time, rebuilds the binaries, and runs
test stages in order until one fails (caught) or all pass (missed):

    cargo mutants --in-place --list --json --diff --package selkd-actor-worker \\
        --file actor-worker/src/rollout.rs > /tmp/rollout.json
    python3 deploy/mutants_e2e.py /tmp/rollout.json target/mutants-e2e/rollout.csv \\
        --build "cargo build --release -p selkd-actor-worker" \\
        --stage "cargo test --release -p selkd-actor-worker" \\
        --stage "cargo test --release -p selkd-tests --test data_path"

Resumable: mutants already in OUT are skipped. The file is restored after each mutant (and on
Ctrl-C or SIGTERM, which end the reading without a row for the mutant in hand and
kill its stage); it refuses to start with uncommitted changes in the mutated files. Outcomes: caught
(with the stage that caught it), missed, unviable (does not build), timeout (a stage ran past
--timeout; counts as caught). Before the first mutant every stage runs once on the unmutated
source and must pass (--no-baseline skips that): a test that fails anyway would catch them all.
Its times set each stage's limit for the mutants, as cargo-mutants does: --timeout-multiplier
times the baseline's, at least --min-timeout, at most --timeout/--stage-timeout; a mutant that
hangs a stage then costs minutes, not the fixed 15. They are kept beside the build (target/
mutants-e2e/<OUT's name>.baseline.json), so a reading resumed with --no-baseline uses them too.
A build past --build-timeout stops the reading without a row: on a machine that busy the
outcome would say nothing about the mutant.
`deploy/mutants.sh` is the learner's in-package reading; docs/mutants.md records both.
"""
import argparse
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time


def sh(cmd, timeout, env=None):
    """Runs `cmd`: "ok", "fail", or "timeout". Then whatever is left of its process group is
    killed, so no cargo or test binary outlives it holding the build lock or the ports, and no
    `selkd train` that a failed test left behind (its learner dies with it) runs on with a
    mutant: one such learner grew to 21 GB in 40 minutes."""
    p = subprocess.Popen(cmd, shell=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, env=env)
    try:
        try:
            result = "ok" if p.wait(timeout=timeout) == 0 else "fail"
        except subprocess.TimeoutExpired:
            result = "timeout"
    finally:
        # Also when the reading is stopped: the stage runs in its own session, out of reach of
        # a signal to the reading's process group.
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass  # nothing left
        p.wait()
    return result


class Stopped(Exception):
    pass


def stop(signum, _frame):
    raise Stopped(signal.Signals(signum).name)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mutants", help="cargo mutants --list --json --diff output")
    p.add_argument("out", help="results CSV (appended; finished mutants are skipped)")
    p.add_argument("--build", required=True, help="shell command that rebuilds what the tests run")
    p.add_argument("--stage", action="append", required=True, help="a test command; first failing one catches")
    p.add_argument("--re", default="", help="only mutants whose name contains this text")
    p.add_argument("--timeout", type=int, default=600, help="seconds per stage")
    p.add_argument("--stage-timeout", type=int, action="append", default=[],
                   help="seconds for the stage of the same position (repeatable; the rest take "
                        "--timeout): a stage of unit tests that runs in a second need not wait "
                        "15 minutes to call a mutant that hangs it a timeout")
    p.add_argument("--build-timeout", type=int, default=3600, help="seconds per build")
    p.add_argument("--timeout-multiplier", type=float, default=5.0,
                   help="a stage's limit is this times its baseline time (when one is known)")
    p.add_argument("--min-timeout", type=int, default=120,
                   help="seconds: the least limit a baseline time can give a stage")
    p.add_argument("--no-baseline", action="store_true",
                   help="skip the stages' run on the unmutated source (a resumed reading whose "
                        "stages passed there before)")
    a = p.parse_args()
    # Set here, not inherited: a shell starts background jobs with SIGINT ignored, and SIGTERM's
    # default would leave the mutant in the source and its stage running.
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)

    mutants = [m for m in json.load(open(a.mutants)) if a.re in m["name"]]
    files = sorted({m["file"] for m in mutants})
    dirty = subprocess.run(["git", "status", "--porcelain", "--", *files], capture_output=True, text=True).stdout
    if dirty.strip():
        diff = subprocess.run(["git", "diff", "--", *files], capture_output=True, text=True).stdout
        if "changed by cargo-mutants" in diff:
            # A reading killed without a signal it could catch (the machine went away) leaves
            # its mutant in the source.
            sys.exit(f"mutants_e2e: a killed reading left a mutant in {' '.join(files)} (git diff shows "
                     f"'changed by cargo-mutants'); restore it with: git checkout -- {' '.join(files)}")
        sys.exit(f"mutants_e2e: uncommitted changes in {' '.join(files)}; commit or stash them first")
    done = set()
    if os.path.exists(a.out):
        done = {row["name"] for row in csv.DictReader(open(a.out))}
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    new = not os.path.exists(a.out)
    with open(a.out, "a", newline="") as f:
        w = csv.writer(f)
        if new:
            w.writerow(["name", "outcome", "stage", "seconds"])
        todo = [m for m in mutants if m["name"] not in done]
        print(f"mutants_e2e: {len(todo)} of {len(mutants)} mutants to run", flush=True)
        times_file = os.path.join("target", "mutants-e2e", os.path.basename(a.out) + ".baseline.json")
        times = None
        if todo and not a.no_baseline:
            times = baseline(a, files)
            with open(times_file, "w") as t:
                json.dump({"stages": a.stage, "seconds": times}, t)
        elif todo and os.path.exists(times_file):
            kept = json.load(open(times_file))
            # Times of other stages say nothing about these.
            if kept["stages"] == a.stage:
                times = kept["seconds"]
        limits = stage_limits(a, times)
        print(f"mutants_e2e: stage limits {limits} s"
              + (f" ({a.timeout_multiplier:g} × the baseline's {[round(t) for t in times]} s)" if times
                 else " (no baseline times: the fixed limits)"), flush=True)
        for i, m in enumerate(todo):
            try:
                run_one(a, m, w, f, i, len(todo), limits)
            except Stopped as e:
                sys.exit(f"mutants_e2e: stopped by {e}; {m['file']} restored, {m['name']} not recorded; run again to continue")
    # Leave the binaries built from the unmutated source.
    sh(a.build, a.build_timeout)


def fixed_limits(a):
    return [a.stage_timeout[n] if n < len(a.stage_timeout) else a.timeout for n in range(len(a.stage))]


def stage_limits(a, times):
    """Each stage's limit in seconds: the fixed one, or, with the baseline's times, the
    multiplier times the stage's, between --min-timeout and the fixed one."""
    fixed = fixed_limits(a)
    if not times:
        return fixed
    return [min(f, max(a.min_timeout, round(a.timeout_multiplier * t))) for f, t in zip(fixed, times)]


def baseline(a, files):
    """Builds and runs every stage on the unmutated source first: a stage that fails there
    would call every mutant reaching it caught. Returns each stage's seconds."""
    t0 = time.time()
    # Touched, so that the builds (the first and any a stage starts) redo what each mutant's
    # redo: the stages' times then include those rebuilds, as a mutant's do.
    for path in files:
        os.utime(path)
    if sh(a.build, a.build_timeout) != "ok":
        sys.exit(f"mutants_e2e: the unmutated source does not build ({a.build}); fix that first")
    failed, times = run_stages(a, fixed_limits(a))
    if failed:
        n, r = failed
        sys.exit(f"mutants_e2e: stage {n} fails ({r}) on the unmutated source, so it would "
                 f"catch every mutant: {a.stage[n - 1]}")
    print(f"mutants_e2e: every stage passes on the unmutated source ({round(time.time() - t0)} s)",
          flush=True)
    return times


def run_stages(a, limits):
    """Runs the stages in order until one does not pass. Returns (its number, "fail" or
    "timeout"), or None when every one passes, and the seconds of the stages run."""
    # The stages' temporary files in a directory of their own, removed after them: a test
    # killed at its timeout leaves its run directory behind, and a mutant that makes the
    # learner log without end (`next_to_log` → `Some((0, 0))`) wrote 15 GB a test into /tmp in
    # 15 minutes, three times over, until the disk was full.
    tmp = os.path.abspath(os.path.join("target", "mutants-e2e", "tmp"))
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    env = dict(os.environ, TMPDIR=tmp)
    times = []
    try:
        for n, (cmd, limit) in enumerate(zip(a.stage, limits), 1):
            t0 = time.time()
            r = sh(cmd, limit, env)
            times.append(time.time() - t0)
            if r != "ok":
                return (n, r), times
        return None, times
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run_one(a, m, w, f, i, total, limits):
    """Applies mutant `m`, builds and runs the stages, restores the file and writes its row (no
    row if the reading is stopped midway)."""
    t0 = time.time()
    try:
        subprocess.run(["patch", "-s", "-p0", m["file"]], input=m["diff"], text=True, check=True)
        outcome, stage = "unviable", ""
        built = sh(a.build, a.build_timeout)
        if built == "timeout":
            # A build that does not finish says the machine is too busy, not that the mutant
            # does not compile: record nothing and stop.
            sys.exit(f"mutants_e2e: building {m['name']} took over {a.build_timeout} s; "
                     "the machine is too busy (or raise --build-timeout); run again to continue")
        if built == "ok":
            outcome = "missed"
            failed, _ = run_stages(a, limits)
            if failed:
                n, r = failed
                outcome, stage = ("caught" if r == "fail" else "timeout"), str(n)
    finally:
        subprocess.run(["git", "checkout", "--", m["file"]], check=True)
    secs = round(time.time() - t0)
    w.writerow([m["name"], outcome, stage, secs])
    f.flush()
    print(f"[{i + 1}/{total}] {outcome:8} {stage:2} {secs:4}s {m['name']}", flush=True)


if __name__ == "__main__":
    main()
