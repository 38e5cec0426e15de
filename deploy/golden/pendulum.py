"""Reference transitions of Gymnasium's Pendulum-v1 for envs/src/pendulum.rs's golden tests.

Run from the repository root (makes a throwaway venv with the pinned versions; needs PyPI):

    bash deploy/golden/pendulum.sh

Torques are float32, as Gymnasium's action space is: under NumPy 2's promotion rules the torque
term 3/(m l^2) * u and the control cost 0.001 * u^2 are then computed in float32 before they meet
the float64 state, and the data records exactly that arithmetic. Each torque is written as the
float64 value of its float32, so a reader gets the very same float32 back.
"""

import json
import sys

import gymnasium
import numpy as np

assert gymnasium.__version__ == "1.4.0", gymnasium.__version__
assert np.__version__.startswith("2."), np.__version__


def f32(x):
    return np.array([x], dtype=np.float32)


def main(out_path):
    rng = np.random.default_rng(20261202)
    env = gymnasium.make("Pendulum-v1")
    env.reset(seed=0)
    pend = env.unwrapped
    rows = []

    # Single steps from arbitrary states, several angles' worth of wrapping, speeds up to and past
    # the clip at 8, torques inside and outside [-2, 2] (the env clips them), and a few exact edges.
    states = [(rng.uniform(-3 * np.pi, 3 * np.pi), rng.uniform(-8.5, 8.5)) for _ in range(480)]
    torques = [rng.uniform(-2.5, 2.5) for _ in range(480)]
    edges = [(np.pi, 0.0, 2.0), (-np.pi, 0.0, -2.0), (0.0, 8.0, 2.0), (0.0, -8.0, -2.0),
             (1e-9, 0.0, 0.0), (np.pi / 2, 7.99, 1.0), (-np.pi / 2, -7.99, -1.0),
             (3.0, 1.0, 1e-3), (-3.0, -1.0, -1e-3), (0.5, 0.5, 1.9999999),
             (2.0, 3.0, 0.1), (-2.0, -3.0, -0.1), (6.0, 0.2, 0.3), (-6.0, -0.2, -0.3),
             (0.7, 0.0, 0.7), (0.7, 0.0, -0.7), (1.3, 4.0, 1.3), (-1.3, -4.0, -1.3),
             (2.9, 7.5, 2.5), (-2.9, -7.5, -2.5)]
    states += [(a, b) for a, b, _ in edges]
    torques += [u for _, _, u in edges]
    for (th, thdot), u in zip(states, torques):
        env.reset()
        pend.state = np.array([th, thdot])
        action = f32(u)
        obs, reward, terminated, truncated, _ = env.step(action)
        rows.append({
            "kind": "step",
            "state": [float(th), float(thdot)],
            "torque": float(action[0]),
            "next_state": [float(v) for v in pend.state],
            "obs": [float(v) for v in obs],
            "reward": float(reward),
        })

    # Whole episodes: 200 steps in a row, the time limit's truncation on the last.
    for _ in range(8):
        env.reset()
        th, thdot = rng.uniform(-np.pi, np.pi), rng.uniform(-1.0, 1.0)
        pend.state = np.array([th, thdot])
        row = {"kind": "trajectory", "state": [float(th), float(thdot)],
               "torques": [], "obs": [], "rewards": [], "truncated": []}
        for _ in range(200):
            action = f32(rng.uniform(-2.2, 2.2))
            obs, reward, terminated, truncated, _ = env.step(action)
            assert not terminated
            row["torques"].append(float(action[0]))
            row["obs"].append([float(v) for v in obs])
            row["rewards"].append(float(reward))
            row["truncated"].append(bool(truncated))
        rows.append(row)

    with open(out_path, "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
