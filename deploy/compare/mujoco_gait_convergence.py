"""Issue 32, docs/results/fidelity.md: how converged is MuJoCo itself on the open-loop cheetah
gait that measures ours? Gymnasium's HalfCheetah-v5 plays the sine gait of envs/src/gaits.rs
(HALFCHEETAH) for 1000 control steps at its shipped 5 x 10 ms and 10x finer (50 x 1 ms), same
control step (0.05 s), seeds 0..SEEDS-1 (Gymnasium's reset noise), and prints the same columns
as our fidelity table: mean distance and return at each, and the gaps |coarse - fine| / |fine|.
Run with the project venv's python (mujoco, gymnasium):
    ~/.cache/selkd/python-venv/bin/python deploy/compare/mujoco_gait_convergence.py [SEEDS]
"""
import sys

import numpy as np

from mujoco_climb_cheetah import episode, make

# envs/src/gaits.rs HALFCHEETAH (frequency, phases), every amplitude 1.
P = [4.22699, -2.7452831, 1.0884578, -1.0541096, 0.44694817, -2.9582198, 1.9110123] + [1.0] * 6


def main():
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    rows = {}
    for name, dt, skip in [("5x10ms (shipped)", 0.01, 5), ("50x1ms (10x finer)", 0.001, 50)]:
        env = make(dt, skip)
        runs = [episode(env, s, "sine", P) for s in range(seeds)]
        rows[name] = np.array(runs)
        d = ", ".join(f"{x:.1f}" for x, _ in runs)
        print(f"{name}: distance {rows[name][:, 0].mean():.1f} m ({d}), return {rows[name][:, 1].mean():.0f}")
    coarse, fine = rows["5x10ms (shipped)"].mean(0), rows["50x1ms (10x finer)"].mean(0)
    gap = np.abs(coarse - fine) / np.abs(fine)
    print(f"MuJoCo, {seeds} seeds: distance gap {100 * gap[0]:.0f}%, return gap {100 * gap[1]:.0f}%")


if __name__ == "__main__":
    main()
