"""Gymnasium envs that misbehave on purpose, for the tests of `gymnasium:` envs.

`SelkdEcho-v0` echoes the action it received (after selkd mapped it onto its Box [-2, 2] x [0, 1])
as its observation; with `boom_at=N` its step raises at step N; with `nan_every=N` every Nth
observation is NaN. With `render_mode="rgb_array"` it draws a `height` x `width` picture whose
red is the last action's second value (0 to 1, as 0 to 255) and whose green counts the steps
(10 a step). `SelkdUnbounded-v0` has an action space with infinite bounds, `SelkdDiscrete-v0` a
Discrete one, `SelkdSquare-v0` draws an 8 x 8 picture and takes no width or height, and
`SelkdBlind-v0` takes a render_mode but has no rgb_array.
"""
import gymnasium as gym
import numpy as np
from gymnasium import spaces


class Echo(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, boom_at=0, nan_every=0, render_mode=None, width=24, height=16, high=None):
        self.render_mode, self.width, self.height = render_mode, width, height
        self.last = 0.0
        self.observation_space = spaces.Box(-np.inf, np.inf, (2, 2), np.float64)
        self.action_space = spaces.Box(
            np.array([-2.0, 0.0], dtype=np.float32), np.array([2.0, 1.0], dtype=np.float32)
        )
        if high is not None:  # a ±high box, which `selkd export` can scale to
            self.action_space = spaces.Box(-high, high, (2,), np.float32)
        self.boom_at, self.nan_every, self.t = boom_at, nan_every, 0

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.last = 0, 0.0
        return np.full((2, 2), self.np_random.uniform(-0.1, 0.1)), {}

    def step(self, action):
        self.t += 1
        if self.boom_at and self.t >= self.boom_at:
            raise RuntimeError(f"boom at step {self.t}")
        a = np.asarray(action, dtype=np.float64)
        self.last = float(a[1])
        obs = np.array([[a[0], a[1]], [a[0], a[1]]])
        if self.nan_every and self.t % self.nan_every == 0:
            obs[0, 0] = np.nan
        return obs, -float(np.sum(a * a)), False, False, {}


    def render(self):
        if self.render_mode != "rgb_array":
            return None
        picture = np.zeros((self.height, self.width, 3), dtype=np.uint8)
        picture[:, :, 0] = min(max(round(255 * self.last), 0), 255)
        picture[:, :, 1] = (10 * self.t) % 256
        return picture


class Square(Echo):
    def __init__(self, render_mode=None):
        super().__init__(render_mode=render_mode, width=8, height=8)


class Blind(Echo):
    metadata = {"render_modes": ["human"], "render_fps": 25}


class Unbounded(Echo):
    def __init__(self):
        super().__init__()
        self.action_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)


class Discrete(Echo):
    def __init__(self):
        super().__init__()
        self.action_space = spaces.Discrete(3)


gym.register("SelkdEcho-v0", entry_point=Echo, max_episode_steps=50)
gym.register("SelkdUnbounded-v0", entry_point=Unbounded, max_episode_steps=50)
gym.register("SelkdDiscrete-v0", entry_point=Discrete, max_episode_steps=50)
gym.register("SelkdSquare-v0", entry_point=Square, max_episode_steps=50)
gym.register("SelkdBlind-v0", entry_point=Blind, max_episode_steps=50)
