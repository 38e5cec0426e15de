"""Why an ant's or a humanoid's episodes end (issue 32: goal 2's ant at 30k env steps, goal 1's
learned checks): uniform random actions or a saved policy on our rapier robot or on Gymnasium's
v5 task, and for each episode whether it ended with the torso above the healthy range (the ant's
z > 1 m: the robot bounced), below it (the ant's z < 0.2 m, the humanoid's z < 1 m: it fell) or at
the time limit. Every such task's observation starts with the torso's height, so the same code
reads either engine.

Usage: python terminations.py ENV_ID [EPISODES] [MODEL.zip]   (ENV_ID: Ant-v5, selkd/Ant-v0,
Humanoid-v5 or selkd/Humanoid-v0; selkd's need the selkd package on the path). Reset seeds
0..EPISODES-1, actions from numpy's default_rng(0), or a saved Stable-Baselines3 SAC policy's
deterministic ones (sb3_sac.py with SB3_SAVE_DIR). Prints one line: the counts, the median (and
mean) episode length and the median of each episode's highest torso, and the mean return ± its
standard deviation over episodes. SB3_ENV_OPTIONS='{"key": value}' (JSON) passes options to
gym.make, as sb3_gait.py (ours: e.g. {"substeps": 50, "solver_iterations": 4} for goal 1's
reference).
"""
import json
import sys

import gymnasium as gym
import numpy as np

from sb3_gait import env_options

env_id = sys.argv[1]
# Each task's healthy torso height, m (Gymnasium's v5 defaults, which ours follow).
HEALTHY = {"Ant": (0.2, 1.0), "Humanoid": (1.0, 2.0)}
task = next((t for t in HEALTHY if t in env_id), None)
if task is None:
    sys.exit(f"terminations: ENV_ID is an Ant or a Humanoid task (got {env_id})")
low, high = HEALTHY[task]
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
above, below = f"above {high:g} m", f"below {low:g} m"
ends = {above: 0, below: 0, "other": 0, "time limit": 0}
lengths, highest, returns = [], [], []
for seed in range(episodes):
    obs, _ = env.reset(seed=seed)
    steps, top, total = 0, obs[0], 0.0
    while True:
        obs, reward, terminated, truncated, _ = env.step(act(obs))
        total += reward
        steps, top, z = steps + 1, max(top, obs[0]), obs[0]
        if terminated:
            ends[above if z > high else below if z < low else "other"] += 1
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
