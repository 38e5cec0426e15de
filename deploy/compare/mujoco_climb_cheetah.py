"""Issue 32, docs/results/fidelity.md: is MuJoCo's own HalfCheetah-v5 converged against a search
aimed at its shipped integration? The same search as our `fidelity::climb_cheetah`
(envs/src/fidelity.rs): open-loop sine gaits a_j = A_j sin(2 pi f t + phi_j) (13 parameters; GAIT
sine) or closed-loop sine + PD gaits (21, GAIT pd: envs/src/gaits.rs `cheetah_pd`), RANDOM random samples then ITERS hill-climbing steps on the mean return of seeds 100-101 at
MuJoCo's shipped 5 x 10 ms, then the best gait over seeds 0-9 at 5 x 10 ms and 10x finer
(50 x 1 ms, same 0.05 s control step). Same ranges and step sizes as the Rust search; numpy's
generator, so not the same draws. Prints one row like the Rust test's.
Run with the project venv's python (mujoco, gymnasium):
    ~/.cache/selkd/python-venv/bin/python deploy/compare/mujoco_climb_cheetah.py [SEED] [GAIT] [RANDOM] [ITERS]
"""
import sys
import time

import gymnasium as gym
import numpy as np


def make(timestep, frame_skip):
    env = gym.make("HalfCheetah-v5", frame_skip=frame_skip)
    env.unwrapped.model.opt.timestep = timestep
    assert abs(env.unwrapped.dt - 0.05) < 1e-12, env.unwrapped.dt
    return env


def act(gait, p, obs, t):
    phase = 2 * np.pi * p[0] * t * 0.05
    if gait == "sine":
        return np.array(p[7:13]) * np.sin(phase + np.array(p[1:7]))
    c, amp, phi = np.array(p[1:19]).reshape(6, 3).T
    target = c + amp * np.sin(phase + phi)
    return np.clip(p[19] * (target - obs[2:8]) - p[20] * obs[11:17], -1.0, 1.0)


def episode(env, seed, gait, p):
    """Distance (m) and return of 1000 control steps of gait `p` from reset `seed`."""
    obs, _ = env.reset(seed=seed)
    x0 = env.unwrapped.data.qpos[0]
    total = 0.0
    for t in range(1000):
        obs, r, terminated, truncated, _ = env.step(act(gait, p, obs, t))
        total += r
        if terminated or truncated:
            break
    return env.unwrapped.data.qpos[0] - x0, total


def main():
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    gait = sys.argv[2] if len(sys.argv) > 2 else "sine"
    assert gait in ("sine", "pd"), f"GAIT is sine or pd, got {gait}"
    n_random = int(sys.argv[3]) if len(sys.argv) > 3 else 60
    iters = int(sys.argv[4]) if len(sys.argv) > 4 else 200
    rng = np.random.default_rng(seed)
    coarse, fine = make(0.01, 5), make(0.001, 50)

    def score(p):
        return np.mean([episode(coarse, s, gait, p)[1] for s in (100, 101)])

    def sample():
        f = [rng.uniform(0.5, 6.0)]
        if gait == "sine":
            return np.concatenate([f, rng.uniform(-np.pi, np.pi, 6), rng.uniform(0, 1, 6)])
        joints = [[rng.uniform(-0.5, 0.5), rng.uniform(0, 1), rng.uniform(-np.pi, np.pi)] for _ in range(6)]
        return np.concatenate([f, np.ravel(joints), [rng.uniform(1, 10), rng.uniform(0, 1)]])

    def perturb(best):
        p = best.copy()
        p[0] = np.clip(p[0] + 0.2 * rng.uniform(-1, 1), 0.3, 8.0)
        if gait == "sine":
            p[1:7] += 0.3 * rng.uniform(-1, 1, 6)
            p[7:] = np.clip(p[7:] + 0.1 * rng.uniform(-1, 1, 6), 0.0, 1.0)
        else:
            p[1:19:3] = np.clip(p[1:19:3] + 0.1 * rng.uniform(-1, 1, 6), -1.0, 1.0)
            p[2:19:3] = np.clip(p[2:19:3] + 0.1 * rng.uniform(-1, 1, 6), 0.0, 1.5)
            p[3:19:3] += 0.3 * rng.uniform(-1, 1, 6)
            p[19] = np.clip(p[19] + rng.uniform(-1, 1), 0.5, 20.0)
            p[20] = np.clip(p[20] + 0.1 * rng.uniform(-1, 1), 0.0, 2.0)
        return p

    start = time.time()
    best, best_score = None, -np.inf
    for _ in range(n_random):
        p = sample()
        s = score(p)
        if s > best_score:
            best, best_score = p, s
    for _ in range(iters):
        p = perturb(best)
        s = score(p)
        if s > best_score:
            best, best_score = p, s
    climb_s = time.time() - start
    at = np.array([episode(coarse, s, gait, best) for s in range(10)])
    ref = np.array([episode(fine, s, gait, best) for s in range(10)])
    (d, r), (fd, fr) = at.mean(0), ref.mean(0)
    print(f"MuJoCo climb ({gait}) seed {seed}: climbed return {best_score:.1f} ({climb_s:.0f} s), gait {[round(float(x), 4) for x in best]}")
    print(f"| HalfCheetah-v5 | 5 x 10 ms ({gait} climbed, seed {seed}) | {d:.2f} | {fd:.2f} | "
          f"{100 * abs(d - fd) / abs(fd):.0f}% | {r:.1f} | {fr:.1f} | {100 * abs(r - fr) / abs(fr):.0f}% |")


if __name__ == "__main__":
    main()
