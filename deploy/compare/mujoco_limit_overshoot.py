"""The MuJoCo side of issue 32's joint-limit measurement: how far MuJoCo's own soft limits let a
planar robot's hinges past their ranges, the reference for the joint-limit frequencies that
`walker2d::tests::limit_frequencies` measures on ours (`SimParams::limit_frequency`;
docs/results/fidelity.md).

Two numbers per hinge, on Gymnasium's MuJoCo v5 task:
- the worst overshoot (rad past the range) under saturated bang-bang torques that flip every 7
  control steps (`[s, -s, s, -s, ...]`), 500 steps from each of reset seeds 0..SEEDS, ignoring
  termination: the robot falls and the floor presses its light feet against their limits;
- the velocities after one zero-action control step from rest at the initial pose with the
  first hinge 4 mrad past its upper limit (0): what a limit does with a reset's small violation.

Usage: ~/.cache/selkd/python-venv/bin/python deploy/compare/mujoco_limit_overshoot.py TASK [SEEDS]
(e.g. Walker2d-v5 4).
"""
import sys

import gymnasium as gym
import numpy as np

task = sys.argv[1]
seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 4
env = gym.make(task)
model, data = env.unwrapped.model, env.unwrapped.data
# The planar robots' first three joints are the root's (rootx, rootz, rooty).
ranges = model.jnt_range[3:]
na = env.action_space.shape[0]

worst = np.zeros(len(ranges))
for seed in range(seeds):
    env.reset(seed=seed)
    for t in range(500):
        s = 1.0 if (t // 7) % 2 == 0 else -1.0
        env.step(np.array([s if i % 2 == 0 else -s for i in range(na)]))
        q = data.qpos[3:]
        worst = np.maximum(worst, np.maximum(q - ranges[:, 1], ranges[:, 0] - q))

env.reset(seed=0)
qpos = env.unwrapped.init_qpos.copy()
qpos[3] = ranges[0, 1] + 0.004
env.unwrapped.set_state(qpos, np.zeros(model.nv))
env.step(np.zeros(na))

print(f"{task}: limits solref {model.jnt_solref[3].tolist()} solimp {model.jnt_solimp[3].tolist()}")
print("worst overshoot, rad, per hinge:", [round(float(x), 3) for x in worst])
print("after one step from 4 mrad past the first hinge's limit: pitch rate "
      f"{data.qvel[2]:.3f} rad/s, that hinge {data.qvel[3]:.3f} rad/s")
