"""Env steps/s of a Gymnasium MuJoCo task, measured the way `selkd bench env` measures ours:
one thread, uniform random actions (drawn before the clock starts), reset on termination or
truncation, resets included.

Usage: python3 deploy/mujoco_env_steps.py Hopper-v5 [STEPS]  ->  "Hopper-v5: X env steps/s"
"""
import sys
import time

import gymnasium as gym
import numpy as np

name = sys.argv[1]
steps = int(sys.argv[2]) if len(sys.argv) > 2 else 10000
env = gym.make(name)
env.reset(seed=0)
low, high = env.action_space.low, env.action_space.high
actions = np.random.default_rng(0).uniform(low, high, size=(steps, low.shape[0]))
actions = actions.astype(np.float32)
start = time.perf_counter()
for a in actions:
    _, _, terminated, truncated, _ = env.step(a)
    if terminated or truncated:
        env.reset()
print(f"{name}: {steps / (time.perf_counter() - start):.0f} env steps/s")
