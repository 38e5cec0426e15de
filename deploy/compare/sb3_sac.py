"""Stable-Baselines3's SAC on a Gymnasium task with its default settings, evaluated as our runs
are: every EVERY env steps, EPISODES deterministic episodes on a separate env. One CSV row per
evaluation: seed,env_steps,mean_return,mean_length (the length tells a policy that stands, whose
return is mostly the healthy reward, from one that moves). Run by deploy/compare/sac-vs-sb3.sh
and sb3-ours-vs-mujoco.sh.

Usage: python sb3_sac.py TASK SEED STEPS [EVERY] [EPISODES]   (e.g. Hopper-v5 1 50000 5000 10)
TASK is any Gymnasium id, ours included (`selkd/HalfCheetah-v0`: the selkd package registers
them). LEARNING_STARTS=N in the environment replaces SB3's default 100 uniform-random steps.
SB3_SAVE_DIR=DIR saves the final policy as DIR/<task with / as ->-seed-<seed>.zip (SB3's format;
deploy/compare/sb3_gait.py replays it and describes its gait). SB3_ENV_OPTIONS='{"key": value}'
(JSON) passes options to gym.make, for both the training and the evaluation env (ours take the
keys of a run config's [env_options], e.g. {"limit_frequency": 7.9}). SB3_END_FLIPPED=1 ends an
episode of a planar task (obs[1] its pitch) once the torso is upside down (cos(pitch) < 0), in
training and in evaluation: a probe of how fast a task can be run upright, not the task itself.
"""
import os
import sys

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from sb3_gait import env_options

# One core per run, as our side (run.threads=1).
torch.set_num_threads(1)
task, seed, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
every = int(sys.argv[4]) if len(sys.argv) > 4 else 1000
episodes = int(sys.argv[5]) if len(sys.argv) > 5 else 10
if task.startswith("selkd/"):
    import selkd  # noqa: F401  (registers selkd/<Name>-v0)
options = env_options()


class EndFlipped(gym.Wrapper):
    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        return obs, r, term or bool(np.cos(obs[1]) < 0), trunc, info


def make():
    env = gym.make(task, **options)
    return EndFlipped(env) if os.environ.get("SB3_END_FLIPPED") == "1" else env


class Evaluate(BaseCallback):
    def __init__(self):
        super().__init__()
        self.env = make()

    def _on_step(self):
        if self.num_timesteps % every == 0:
            returns, lengths = [], []
            for e in range(episodes):
                obs, _ = self.env.reset(seed=1_000_000 + 1000 * self.num_timesteps + e)
                done, total, length = False, 0.0, 0
                while not done:
                    action, _ = self.model.predict(obs, deterministic=True)
                    obs, r, term, trunc, _ = self.env.step(action)
                    total += r
                    length += 1
                    done = term or trunc
                returns.append(total)
                lengths.append(length)
            print(
                f"{seed},{self.num_timesteps},{np.mean(returns):.3f},{np.mean(lengths):.1f}",
                flush=True,
            )
        return True


# SB3's defaults for SAC: lr 3e-4, buffer 1e6, learning_starts 100, batch 256, tau 0.005,
# gamma 0.99, train_freq 1, gradient_steps 1, ent_coef "auto" (target entropy −|A|), [256, 256].
starts = int(os.environ.get("LEARNING_STARTS", 100))
model = SAC("MlpPolicy", make(), seed=seed, device="cpu", verbose=0, learning_starts=starts)
model.learn(total_timesteps=steps, callback=Evaluate())
if os.environ.get("SB3_SAVE_DIR"):
    os.makedirs(os.environ["SB3_SAVE_DIR"], exist_ok=True)
    model.save(os.path.join(os.environ["SB3_SAVE_DIR"], f"{task.replace('/', '-')}-seed-{seed}"))
