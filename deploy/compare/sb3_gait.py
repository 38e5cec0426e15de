"""What a saved Stable-Baselines3 policy does on a planar task (hopper, walker2d, halfcheetah), on
our rapier env or on Gymnasium's MuJoCo one: issue 32's goal 2 compares the gait where returns
differ (forward speed, height, episode length), and this says how a policy moves, not only what
it earns. Deterministic episodes, seeds 0..EPISODES-1; one Markdown table row per policy and env.

Usage: python sb3_gait.py MODEL.zip ENV_ID [EPISODES]
  MODEL.zip from sb3_sac.py with SB3_SAVE_DIR set; ENV_ID e.g. HalfCheetah-v5 or
  selkd/HalfCheetah-v0 (a policy may be replayed on the other engine: same spaces).
  --header prints the table's header instead. SB3_ENV_OPTIONS='{"key": value}' (JSON) passes
  options to gym.make (ours: a run config's [env_options] keys, e.g. {"substeps": 50}).

Columns: return; episode length; forward speed (mean of qvel[0], m/s); torso height (mean of
qpos[1]: relative to the model's rest height on the cheetah, absolute on the hopper and walker);
pitch (mean |qpos[2]|, rad); upside down (share of steps with cos(pitch) < 0); at limits (share of
steps with the joint within 0.05 rad of or past a limit of the XML's range, each joint in the
XML's order); overshoot (the 99th percentile, over all steps and joints, of how far a joint is
past its range, rad: MuJoCo's limits are soft, rapier's hard unless `limit_frequency` says); stride (the dominant frequency of the first joint's angle, Hz); action size (mean
of the squared action, the cost's term before its weight).
"""
import json
import os
import sys

import gymnasium as gym
import numpy as np

# The XML's joint ranges, rad (Gymnasium's hopper.xml, walker2d.xml, half_cheetah.xml).
RANGES = {
    "Hopper": [(-2.61799, 0.0), (-2.61799, 0.0), (-0.785398, 0.785398)],
    "Walker2d": [(-2.61799, 0.0), (-2.61799, 0.0), (-0.785398, 0.785398)] * 2,
    "HalfCheetah": [(-0.52, 1.05), (-0.785, 0.785), (-0.4, 0.785), (-1.0, 0.7), (-1.2, 0.87), (-0.5, 0.5)],
}
NEAR = 0.05
CONTROL_DT = {"Hopper": 0.008, "Walker2d": 0.008, "HalfCheetah": 0.05}

HEADER = (
    "| policy | env | return | length | forward m/s | height | pitch | upside down | at limits | "
    "overshoot | stride Hz | action² |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def env_options():
    """SB3_ENV_OPTIONS (JSON) from the environment: keyword options to gym.make (ours take a run
    config's [env_options] keys). The one reader of it for every script here that takes it
    (sb3_sac.py, one_step_vs_mujoco.py, terminations.py)."""
    return json.loads(os.environ.get("SB3_ENV_OPTIONS") or "{}")


def family(env_id):
    for name in RANGES:
        if name in env_id:
            return name
    sys.exit(f"sb3_gait: {env_id} is not a planar task (Hopper, Walker2d, HalfCheetah)")


def main():
    if sys.argv[1:] == ["--header"]:
        print(HEADER)
        return
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    path, env_id = sys.argv[1], sys.argv[2]
    episodes = int(sys.argv[3]) if len(sys.argv) > 3 else 10
    if env_id.startswith("selkd/"):
        import selkd  # noqa: F401  (registers selkd/<Name>-v0)
    from stable_baselines3 import SAC

    fam = family(env_id)
    ranges = np.array(RANGES[fam])
    nj = len(ranges)
    model = SAC.load(path, device="cpu")
    options = env_options()
    env = gym.make(env_id, **options)
    returns, lengths, speed, height, pitch, flipped, limits, past, stride, act2 = ([] for _ in range(10))
    for e in range(episodes):
        obs, _ = env.reset(seed=e)
        done, total, joints = False, 0.0, []
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, _ = env.step(action)
            total += r
            done = term or trunc
            # obs = qpos[1:] (height, pitch, joints), then qvel (forward speed first).
            height.append(obs[0])
            pitch.append(abs(obs[1]))
            flipped.append(np.cos(obs[1]) < 0)
            speed.append(obs[2 + nj])
            q = obs[2 : 2 + nj]
            joints.append(q)
            limits.append((q < ranges[:, 0] + NEAR) | (q > ranges[:, 1] - NEAR))
            past.extend(np.maximum(np.maximum(ranges[:, 0] - q, q - ranges[:, 1]), 0.0))
            act2.append(float(np.mean(np.square(np.clip(action, -1, 1)))))
        returns.append(total)
        lengths.append(len(joints))
        if len(joints) >= 16:
            a = np.array(joints)[:, 0]
            power = np.abs(np.fft.rfft(a - a.mean())) ** 2
            freqs = np.fft.rfftfreq(len(a), CONTROL_DT[fam])
            stride.append(freqs[1:][np.argmax(power[1:])])
    at = np.mean(np.array(limits), axis=0)
    where = env_id + (" " + json.dumps(options) if options else "")
    print(
        f"| {path.rsplit('/', 1)[-1]} | {where} | {np.mean(returns):.0f} ± {np.std(returns):.0f} | "
        f"{np.mean(lengths):.0f} | {np.mean(speed):.2f} | {np.mean(height):.3f} | {np.mean(pitch):.2f} | "
        f"{100 * np.mean(flipped):.0f}% | {' '.join(f'{100 * x:.0f}' for x in at)}% | {np.percentile(past, 99):.3f} | "
        f"{np.median(stride) if stride else float('nan'):.2f} | {np.mean(act2):.2f} |"
    )


if __name__ == "__main__":
    main()
