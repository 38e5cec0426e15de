"""The tasks as Gymnasium environments: ``SelkdEnv`` (one env) and ``SelkdVectorEnv`` (n envs
stepped together in Rust, on threads), both over ``selkd._native``.

``import selkd`` registers every env of the Rust registry under ``selkd/<Name>-v0``; keyword
arguments of ``gymnasium.make`` besides ``render_mode``, ``width`` and ``height`` are the env's
options (the keys of a run config's ``[env_options]``).
"""

from __future__ import annotations

import functools
import json
import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _native

# Gymnasium name of each registry env. A registry env missing here fails the package's tests.
GYMNASIUM_NAMES = {
    "pendulum": "Pendulum",
    "hopper": "Hopper",
    "walker2d": "Walker2d",
    "halfcheetah": "HalfCheetah",
    "ant": "Ant",
    "ant-contacts": "AntContacts",
    "humanoid": "Humanoid",
    "fpc-assembly": "FpcAssembly",
}
VERSION = 0


def gymnasium_id(name: str) -> str:
    """``selkd/Hopper-v0`` for the registry name ``hopper``."""
    return f"selkd/{GYMNASIUM_NAMES[name]}-v{VERSION}"


def registry_name(env_id: str) -> str:
    """The registry name for a Gymnasium id (``selkd/Hopper-v0`` → ``hopper``)."""
    for name, gym_name in GYMNASIUM_NAMES.items():
        if env_id == f"selkd/{gym_name}-v{VERSION}":
            return name
    raise _native.SelkdError(
        f"unknown env id {env_id!r}; known: {', '.join(gymnasium_id(n) for n in _native.names())}"
    )


def _options_json(name: str, options: dict[str, Any]) -> str:
    try:
        return json.dumps(options, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise _native.SelkdError(
            f"options for `{name}`: {e}; pass numbers, strings, booleans or lists"
        ) from None


def _fresh_seed() -> int:
    # Gymnasium's envs draw an unseeded first episode from the OS's entropy; so do we.
    return int.from_bytes(os.urandom(8), "little") >> 1


class SelkdEnv(gym.Env):
    """One env of the Rust registry with Gymnasium's API.

    Observations are float32 ``Box(-inf, inf)``; actions float32 ``Box(-1, 1)`` (the env scales
    them to its actuators). ``info["success"]`` carries the task's success where it has one (the
    assembly task, at an episode's end). ``render_mode="rgb_array"`` draws with the ray caster,
    ``width`` × ``height`` pixels.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        name: str,
        render_mode: str | None = None,
        width: int = 320,
        height: int = 240,
        **options: Any,
    ):
        if render_mode not in (None, "rgb_array"):
            raise _native.SelkdError(
                f"render_mode={render_mode!r}: selkd envs draw only 'rgb_array' (or pass None)"
            )
        self._env = _native.Env(name, _options_json(name, options), render_mode is not None)
        # Read once: each `.spec` read builds a new object, and `step` needs the action size.
        self._env_spec = self._env.spec
        self.name = name
        self.options = dict(options)
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        dt = self._env_spec.control_dt
        self.metadata = {**self.metadata, "render_fps": round(1.0 / dt) if dt else 30}
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, (self._env_spec.obs_dim,), np.float32
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self._env_spec.act_dim,), np.float32)
        self._seeded = False

    @property
    def max_episode_steps(self) -> int:
        """The env's own time limit (it truncates there)."""
        return self._env_spec.max_episode_steps

    @property
    def gymnasium_action_scale(self) -> float:
        """Gymnasium's own version of the task takes this times our action."""
        return self._env_spec.gymnasium_action_scale

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options:
            raise _native.SelkdError(
                f"reset options {sorted(options)}: selkd envs take their options at make time "
                f"(gymnasium.make(id, key=value))"
            )
        if seed is None and not self._seeded:
            seed = _fresh_seed()
        if seed is not None:
            if not 0 <= seed < 2**64:
                raise _native.SelkdError(f"seed {seed}: must be 0 to 2**64 - 1")
            self._seeded = True
        return self._env.reset(seed), {}

    def step(self, action):
        a = np.asarray(action, dtype=np.float32)
        n = self._env_spec.act_dim
        if a.shape != (n,):
            if a.size != n:
                raise _native.SelkdError(
                    f"{gymnasium_id(self.name)}: the action has shape {a.shape}, expected ({n},)"
                )
            a = a.reshape(n)
        obs, reward, terminated, truncated, success = self._env.step(a)
        info = {} if success is None else {"success": success}
        return obs, reward, terminated, truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn(
                "render() called without a render mode; make the env with render_mode='rgb_array'"
            )
            return None
        return self._env.render(self.width, self.height)


class SelkdVectorEnv(VectorEnv):
    """``num_envs`` envs of one kind stepped together in Rust, on ``threads`` threads (0: one
    per core), with no Python call per env. Gymnasium's next-step autoreset: the step after an
    env's episode ends resets it (its action is ignored; reward 0, neither flag set).

    ``reset(seed=s)`` seeds env i with ``s + i`` (or with ``seed[i]`` for a list).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self, name: str, num_envs: int, threads: int = 0, max_episode_steps: int | None = None,
        **options: Any,
    ):
        self._envs = _native.VecEnv(name, int(num_envs), _options_json(name, options), int(threads))
        self._env_spec = self._envs.spec
        if max_episode_steps is not None and max_episode_steps != self._env_spec.max_episode_steps:
            raise _native.SelkdError(
                f"max_episode_steps={max_episode_steps}: selkd/{name}'s time limit is "
                f"{self._env_spec.max_episode_steps} and cannot be changed in the vector form"
            )
        self.name = name
        self.num_envs = self._envs.num_envs
        self.single_observation_space = gym.spaces.Box(
            -np.inf, np.inf, (self._env_spec.obs_dim,), np.float32
        )
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (self._env_spec.act_dim,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._seeded = False

    @property
    def threads(self) -> int:
        return self._envs.threads

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        if options:
            raise _native.SelkdError(
                f"reset options {sorted(options)}: selkd envs take their options at make time"
            )
        if seed is None and not self._seeded:
            seed = _fresh_seed()
        if isinstance(seed, int):
            super().reset(seed=seed)
            seeds = [seed + i for i in range(self.num_envs)]
        elif seed is None:
            seeds = [None] * self.num_envs
        else:
            seeds = list(seed)
        self._seeded = True
        return self._envs.reset(seeds), {}

    def step(self, actions):
        a = np.ascontiguousarray(actions, dtype=np.float32)
        obs, rewards, terminated, truncated, success = self._envs.step(a)
        infos: dict[str, Any] = {}
        has = success >= 0
        if has.any():
            infos = {"success": success == 1, "_success": has}
        return obs, rewards, terminated, truncated, infos


def register_all() -> None:
    """Registers every env of the Rust registry with Gymnasium (done by ``import selkd``)."""
    for name in _native.names():
        env_id = gymnasium_id(name)
        if env_id in gym.registry:
            continue
        spec = _native.Env(name).spec
        gym.register(
            env_id,
            # partials of the classes, not closures: envs must pickle (subprocess vector envs).
            entry_point=functools.partial(SelkdEnv, name),
            vector_entry_point=functools.partial(SelkdVectorEnv, name),
            max_episode_steps=spec.max_episode_steps,
        )
