#!/usr/bin/env python3
"""Published Gym MuJoCo learning curves at given env-step budgets, as one small CSV.

Sources (read, not copied into the project: only the summary numbers are written, with their
source named on every row):
  - SimbaV2's repository (github.com/dojeon-ai/SimbaV2, results/baseline/*.csv): per-seed curves of
    SAC, REDQ (UTD 20), DroQ (UTD 20), CrossQ, BRO and SimbaV2 on Gym's *-v4 tasks, evaluated every
    16 666 env steps.
  - MR.Q's repository (github.com/facebookresearch/MRQ, results/gym_results.txt): per-seed curves of
    MR.Q on Gym's *-v4 tasks, every 5 000 env steps.

    python3 deploy/published_baselines.py SIMBAV2_CLONE MRQ_CLONE > docs/results/published/gym-mujoco-v4.csv

For each (source, method, task) and each budget B in BUDGETS, the row holds the evaluation nearest
to B (its env step is written, so a reader sees SimbaV2's 99 996 for 100k), over all seeds: the
number of seeds, mean, sample std, min and max of the return. A budget with no evaluation
within 20% of it has no row.
"""

import csv
import math
import sys
from pathlib import Path

BUDGETS = [30_000, 50_000, 100_000, 300_000]
TASKS = ["Hopper", "Walker2d", "HalfCheetah", "Ant", "Humanoid"]
SIMBA_FILES = {
    "sac.csv": "SAC",
    "redq_utd20.csv": "REDQ (UTD 20)",
    "droq_utd20.csv": "DroQ (UTD 20)",
    "crossq.csv": "CrossQ",
    "bro_utd10.csv": "BRO (UTD 10)",
    "simbaV2_utd8.csv": "SimbaV2 (UTD 8)",
}


def summary(values):
    n = len(values)
    mean = sum(values) / n
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else float("nan")
    return n, mean, std, min(values), max(values)


def nearest(steps, budget):
    """The evaluation nearest the budget, or None if none is within 20% of it (SimbaV2's own
    curves are evaluated every 50k: its 50k is not a 30k result)."""
    s = min(steps, key=lambda s: (abs(s - budget), s))
    return s if abs(s - budget) <= 0.2 * budget else None


def simba_rows(root):
    for name, method in SIMBA_FILES.items():
        path = root / "results" / "baseline" / name
        if not path.exists():
            sys.exit(f"published_baselines: {path} is missing; pass a clone of dojeon-ai/SimbaV2")
        curves = {}  # (task, step) -> [returns over seeds]
        for r in csv.DictReader(open(path)):
            if r["metric"] != "avg_return":
                continue
            # SimbaV2's own curves spell the id Hopper_v4, the others Hopper-v4.
            env = r["env_name"].replace("_v4", "-v4")
            task = env.removesuffix("-v4")
            if task not in TASKS or env == task:
                continue
            curves.setdefault((task, float(r["env_step"])), []).append(float(r["value"]))
        for task in TASKS:
            steps = sorted(s for t, s in curves if t == task)
            for b in BUDGETS:
                s = nearest(steps, b) if steps else None
                if s is not None:
                    yield ("SimbaV2 repo results/baseline/" + name, method, task, b, int(s), *summary(curves[(task, s)]))


def mrq_rows(path):
    if not path.exists():
        sys.exit(f"published_baselines: {path} is missing; pass a clone of facebookresearch/MRQ")
    task, table = None, {}
    for line in open(path):
        line = line.strip()
        if line.startswith("Env: Gym-"):
            task = line.removeprefix("Env: Gym-").removesuffix("-v4")
            table[task] = {}
        elif task and line and line[0].isdigit():
            cells = line.split()
            table[task][float(cells[0])] = [float(c) for c in cells[1:]]
    for task in TASKS:
        steps = sorted(table.get(task, {}))
        for b in BUDGETS:
            s = nearest(steps, b) if steps else None
            if s is not None:
                yield ("MRQ repo results/gym_results.txt", "MR.Q", task, b, int(s), *summary(table[task][s]))


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: published_baselines.py SIMBAV2_CLONE MRQ_CLONE")
    out = csv.writer(sys.stdout, lineterminator="\n")
    out.writerow(["source", "method", "task", "budget_env_steps", "env_step", "seeds", "mean", "std", "min", "max"])
    rows = list(simba_rows(Path(sys.argv[1]))) + list(mrq_rows(Path(sys.argv[2]) / "results" / "gym_results.txt"))
    for row in rows:
        out.writerow([*row[:6], *(f"{v:.1f}" for v in row[6:])])


if __name__ == "__main__":
    main()
