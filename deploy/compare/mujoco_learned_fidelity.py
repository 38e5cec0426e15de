"""Issue 32's learned-policy check run on MuJoCo itself: how far a policy trained on Gymnasium's
MuJoCo v5 task at its own integration (frame_skip × timestep, e.g. Walker2d's 4 × 2 ms) keeps its
return and episode length when the same control step is integrated 10× finer (10 × frame_skip
steps of timestep / 10). It calibrates the criterion our rapier tasks are held to
(`deploy/compare/learned-policy-fidelity.sh`: within 15%): a task that MuJoCo's own policies do
not keep within 15% cannot be asked to.

Stable-Baselines3's SAC with its defaults, except `learning_starts` = 256 as our check's warm-up
(the same sizes as our check's SAC: [256, 256], batch 256, one update per env step), trained STEPS
env steps on one thread; then its deterministic policy on EPISODES fresh episodes (reset seeds
2_000_000 + e) at both integrations. Prints one CSV line per seed:
task,seed,return,length,fine_return,fine_length.

Usage: ~/.cache/selkd/python-venv/bin/python deploy/compare/mujoco_learned_fidelity.py \\
           TASK SEED STEPS [EPISODES]     (e.g. Walker2d-v5 1 30000 50)
"""
import sys

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC

torch.set_num_threads(1)
task, seed, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
episodes = int(sys.argv[4]) if len(sys.argv) > 4 else 50

model = SAC("MlpPolicy", gym.make(task), seed=seed, device="cpu", verbose=0, learning_starts=256)
model.learn(total_timesteps=steps)


def replay(finer):
    """Mean return and length over the episodes, integrated `finer` times finer."""
    base = gym.make(task)
    env = gym.make(task, frame_skip=base.unwrapped.frame_skip * finer)
    env.unwrapped.model.opt.timestep = base.unwrapped.model.opt.timestep / finer
    assert abs(env.unwrapped.dt - base.unwrapped.dt) < 1e-9, "the control step must not change"
    returns, lengths = [], []
    for e in range(episodes):
        obs, _ = env.reset(seed=2_000_000 + e)
        done, total, n = False, 0.0, 0
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, _ = env.step(action)
            total, n, done = total + r, n + 1, term or trunc
        returns.append(total)
        lengths.append(n)
    return np.mean(returns), np.mean(lengths)


r, n = replay(1)
rf, nf = replay(10)
print(f"{task},{seed},{r:.1f},{n:.1f},{rf:.1f},{nf:.1f}", flush=True)
