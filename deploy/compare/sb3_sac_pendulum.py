"""Stable-Baselines3's SAC on Gymnasium's Pendulum-v1 with its default settings, evaluated as our
runs are: every 1000 env steps, 10 deterministic episodes. One CSV row per evaluation:
seed,env_steps,mean_return. Run by deploy/compare/sac-vs-sb3.sh (which makes its venv)."""
import sys

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

torch.set_num_threads(1)
seed, steps = int(sys.argv[1]), int(sys.argv[2])


class Evaluate(BaseCallback):
    def __init__(self):
        super().__init__()
        self.env = gym.make("Pendulum-v1")

    def _on_step(self):
        if self.num_timesteps % 1000 == 0:
            returns = []
            for e in range(10):
                obs, _ = self.env.reset(seed=1_000_000 + 1000 * self.num_timesteps + e)
                done, total = False, 0.0
                while not done:
                    action, _ = self.model.predict(obs, deterministic=True)
                    obs, r, term, trunc, _ = self.env.step(action)
                    total += r
                    done = term or trunc
                returns.append(total)
            print(f"{seed},{self.num_timesteps},{np.mean(returns):.3f}", flush=True)
        return True


# SB3's defaults for SAC: lr 3e-4, buffer 1e6, learning_starts 100, batch 256, tau 0.005,
# gamma 0.99, train_freq 1, gradient_steps 1, ent_coef "auto" (target entropy −|A|), [256, 256].
model = SAC("MlpPolicy", gym.make("Pendulum-v1"), seed=seed, device="cpu", verbose=0)
model.learn(total_timesteps=steps, callback=Evaluate())
