"""One control step of our planar task against MuJoCo's, from the same states: a saved SB3 policy
drives our env; from each state of its episode MuJoCo's v5 task of the same name (integrated 10x
finer than its own setting: a converged reference) takes the same action, and the two changes of
forward velocity are compared. A step where a foot lands shows what the contacts deliver; a step
in the air what the articulation does. This is how the planar robots' missing foot friction was
found (docs/results/fidelity.md, "Read first"): steps in the air agreed, steps with a landing fell
short on ours.

Usage: python one_step_vs_mujoco.py MODEL.zip TASK [STEPS] [--rows]
  TASK: hopper, walker2d or halfcheetah; STEPS (default 300) of one deterministic episode, seed 0;
  --rows prints one line per step. SB3_ENV_OPTIONS='{"key": value}' (JSON) sets our env's
  [env_options] keys (e.g. {"substeps": 50}).

Prints the summed change of forward velocity (qvel[0]) on each engine, over all steps and over
the steps where MuJoCo had a contact, and the RMS difference of every qvel component after the
step. Our hopper and walker clip the observed velocities at 10 m/s (rad/s); states read back from
such an observation are not exact, so read those tasks' numbers with that in mind.
"""
import sys

import gymnasium as gym
import mujoco
import numpy as np

import selkd  # noqa: F401  (registers selkd/*)
from stable_baselines3 import SAC

from sb3_gait import env_options

NAMES = {"hopper": "Hopper", "walker2d": "Walker2d", "halfcheetah": "HalfCheetah"}


def main(argv):
    rows = "--rows" in argv
    argv = [a for a in argv if a != "--rows"]
    if len(argv) < 2 or argv[1] not in NAMES:
        print(__doc__, file=sys.stderr)
        return 2
    model = SAC.load(argv[0], device="cpu")
    name = NAMES[argv[1]]
    steps = int(argv[2]) if len(argv) > 2 else 300
    options = env_options()
    ours = gym.make(f"selkd/{name}-v0", **options)
    reference = gym.make(f"{name}-v5")
    u = reference.unwrapped
    skip = u.frame_skip * 10
    u.model.opt.timestep /= 10
    m, d = u.model, u.data
    reference.reset(seed=0)
    obs, _ = ours.reset(seed=0)
    nq = m.nq
    dv_ours, dv_ref, touched, sq = [], [], [], np.zeros(m.nv)
    for t in range(steps):
        action, _ = model.predict(obs, deterministic=True)
        # Our observation is qpos without x, then qvel: the whole state of a planar robot (x
        # does not matter on a flat floor).
        q = np.concatenate([[0.0], obs[: nq - 1]]).astype(np.float64)
        v = obs[nq - 1 : nq - 1 + m.nv].astype(np.float64)
        d.qpos[:], d.qvel[:] = q, v
        d.qacc_warmstart[:] = 0
        mujoco.mj_forward(m, d)
        d.ctrl[:] = np.clip(action, -1, 1)
        contact = False
        for _ in range(skip):
            mujoco.mj_step(m, d)
            contact |= d.ncon > 0
        obs, _, terminated, truncated, _ = ours.step(action)
        v_ours = obs[nq - 1 : nq - 1 + m.nv]
        dv_ours.append(v_ours[0] - v[0])
        dv_ref.append(d.qvel[0] - v[0])
        touched.append(contact)
        sq += (v_ours - d.qvel) ** 2
        if rows:
            print(f"{t:4} vx {v[0]:+6.2f}  d(vx) ours {dv_ours[-1]:+.3f} MuJoCo {dv_ref[-1]:+.3f}"
                  f"  {'contact' if contact else 'in the air'}")
        if terminated or truncated:
            break
    n = len(dv_ours)
    dv_ours, dv_ref, touched = np.array(dv_ours), np.array(dv_ref), np.array(touched)
    print(f"{argv[0]} on selkd/{name}-v0 {options or ''}, {n} steps; MuJoCo {name}-v5 at "
          f"{m.opt.timestep * 1000:g} ms x {skip}")
    print(f"  summed d(vx): ours {dv_ours.sum():.2f}, MuJoCo {dv_ref.sum():.2f} m/s; steps with a "
          f"contact ({touched.sum()}): ours {dv_ours[touched].sum():.2f}, MuJoCo "
          f"{dv_ref[touched].sum():.2f}; in the air: ours {dv_ours[~touched].sum():.2f}, "
          f"MuJoCo {dv_ref[~touched].sum():.2f}")
    print("  RMS qvel difference after the step:", np.round(np.sqrt(sq / n), 2).tolist())
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
