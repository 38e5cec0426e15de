"""Env steps/s of a Gymnasium env from a Python loop, measured the way `selkd bench env` measures
ours in Rust: one process, uniform random actions drawn before the clock starts, reset on
termination or truncation, resets included. Works for Gymnasium's MuJoCo tasks (`Hopper-v5`) and
for ours through the selkd package (`selkd/Hopper-v0`).

Usage: python deploy/gym_env_steps.py ID [STEPS] [--vector N [--sync]]  ->  "ID: X env steps/s"
  --vector N   gymnasium.make_vec with N envs (steps counted over all envs); selkd's own vector
               env for selkd ids, Gymnasium's SyncVectorEnv with --sync (and for every other id).
"""
import argparse
import time

import gymnasium as gym
import numpy as np

p = argparse.ArgumentParser()
p.add_argument("id")
p.add_argument("steps", type=int, nargs="?", default=10000)
p.add_argument("--vector", type=int, default=0)
p.add_argument("--sync", action="store_true")
args = p.parse_args()
if args.id.startswith("selkd/"):
    import selkd  # noqa: F401  (registers the ids)

if args.vector:
    mode = "sync" if args.sync or not args.id.startswith("selkd/") else None
    env = gym.make_vec(args.id, num_envs=args.vector, vectorization_mode=mode)
    env.reset(seed=0)
    space = env.action_space
    calls = max(1, args.steps // args.vector)
    actions = np.random.default_rng(0).uniform(space.low, space.high, (calls, *space.shape))
    actions = actions.astype(np.float32)
    start = time.perf_counter()
    for a in actions:
        env.step(a)  # both autoreset on the next step
    rate = calls * args.vector / (time.perf_counter() - start)
else:
    env = gym.make(args.id)
    env.reset(seed=0)
    low, high = env.action_space.low, env.action_space.high
    actions = np.random.default_rng(0).uniform(low, high, size=(args.steps, low.shape[0]))
    actions = actions.astype(np.float32)
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    rate = args.steps / (time.perf_counter() - start)
print(f"{args.id}: {rate:.0f} env steps/s")
