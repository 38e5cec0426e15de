"""The MuJoCo side of issue 32's reward bands: the mean return of a uniform random policy and of
zero actions (standing) on Gymnasium's MuJoCo v5 task, over reset seeds 0..SEEDS, for the band
tests `<task>::tests::random_and_standing_returns_stay_in_band` (docs/results/fidelity.md).

Usage: ~/.cache/selkd/python-venv/bin/python deploy/compare/mujoco_random_standing.py TASK [SEEDS]
(e.g. Ant-v5 10). Prints one line: task, random mean return and length, standing mean return and
length.
"""
import sys

import gymnasium as gym
import numpy as np

task = sys.argv[1]
seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 10
env = gym.make(task)


def episode(seed, policy):
    env.reset(seed=seed)
    total, steps, done = 0.0, 0, False
    while not done:
        _, r, term, trunc, _ = env.step(policy())
        total, steps, done = total + r, steps + 1, term or trunc
    return total, steps


def mean(eps):
    return np.mean([e[0] for e in eps]), np.mean([e[1] for e in eps])


rng = np.random.default_rng(1000)
low, high = env.action_space.low, env.action_space.high
random = [episode(s, lambda: rng.uniform(low, high).astype(np.float32)) for s in range(seeds)]
zero = [episode(s, lambda: np.zeros_like(low)) for s in range(seeds)]
(rr, rl), (zr, zl) = mean(random), mean(zero)
print(f"{task}: random {rr:.1f} ({rl:.0f} steps), standing {zr:.1f} ({zl:.0f} steps)")
