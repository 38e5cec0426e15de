"""Why an ant's episodes end (issue 32, goal 2's ant at 30k env steps): uniform random actions on
our rapier ant or on Gymnasium's Ant-v5, and for each episode whether it ended with the torso
above the healthy range (z > 1 m: the robot bounced), below it (z < 0.2 m) or at the time limit.
Both tasks' observations start with the torso's height, so the same code reads either.

Usage: python ant_terminations.py ENV_ID [EPISODES] [MODEL.zip]   (ENV_ID: Ant-v5 or
selkd/Ant-v0; selkd's needs the selkd package on the path). Reset seeds 0..EPISODES-1, actions
from numpy's default_rng(0), or a saved Stable-Baselines3 SAC policy's deterministic ones
(sb3_sac.py with SB3_SAVE_DIR). Prints one line: the counts, the median (and mean) episode length and the
median of each episode's highest torso, and the mean return ± its standard deviation over
episodes. SB3_ENV_OPTIONS='{"key": value}' (JSON) passes options to gym.make, as sb3_gait.py
(ours: e.g. {"substeps": 50, "solver_iterations": 4} for goal 1's reference).
"""
import json
import sys

import gymnasium as gym
import numpy as np

from sb3_gait import env_options

env_id = sys.argv[1]
episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 50
if env_id.startswith("selkd/"):
    import selkd  # noqa: F401  (registers selkd/*)
options = env_options()
env = gym.make(env_id, **options)
rng = np.random.default_rng(0)
if len(sys.argv) > 3:
    from stable_baselines3 import SAC

    model = SAC.load(sys.argv[3], device="cpu")
    act = lambda obs: model.predict(obs, deterministic=True)[0]  # noqa: E731
else:
    act = lambda obs: rng.uniform(-1.0, 1.0, env.action_space.shape)  # noqa: E731
ends = {"above 1 m": 0, "below 0.2 m": 0, "other": 0, "time limit": 0}
lengths, highest, returns = [], [], []
for seed in range(episodes):
    obs, _ = env.reset(seed=seed)
    steps, top, total = 0, obs[0], 0.0
    while True:
        obs, reward, terminated, truncated, _ = env.step(act(obs))
        total += reward
        steps, top, z = steps + 1, max(top, obs[0]), obs[0]
        if terminated:
            ends["above 1 m" if z > 1.0 else "below 0.2 m" if z < 0.2 else "other"] += 1
            break
        if truncated:
            ends["time limit"] += 1
            break
    lengths.append(steps)
    returns.append(total)
    highest.append(top)
what = sys.argv[3] if len(sys.argv) > 3 else "random"
where = env_id + (" " + json.dumps(options) if options else "")
print(f"{where}: {episodes} {what} episodes, ends {ends}, median length {np.median(lengths):.0f} (mean {np.mean(lengths):.1f}), "
      f"median highest torso {np.median(highest):.3f} m, "
      f"return {np.mean(returns):.0f} ± {np.std(returns):.0f}")
