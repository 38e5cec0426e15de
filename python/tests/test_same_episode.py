"""The same seed gives the same episode through Python as through Rust, bit for bit: the
episodes in SELKD_TEST_EPISODES were stepped by tests/tests/python.rs on the Rust crate."""

import json
import os

import gymnasium as gym
import numpy as np

import selkd


def bits32(a):
    return np.asarray(a, np.float32).view(np.uint32).tolist()


def test_every_env_repeats_the_rust_episode():
    episodes = json.load(open(os.environ["SELKD_TEST_EPISODES"]))
    assert {e["env"] for e in episodes} == set(selkd.names())
    for ep in episodes:
        env = gym.make(selkd.gymnasium_id(ep["env"]))
        obs, _ = env.reset(seed=ep["seed"])
        assert bits32(obs) == ep["first_obs_bits"], ep["env"]
        for t, step in enumerate(ep["steps"]):
            obs, reward, terminated, truncated, info = env.step(np.array(step["action"], np.float32))
            where = f"{ep['env']} step {t}"
            assert bits32(obs) == step["obs_bits"], where
            assert np.float64(reward).view(np.uint64) == np.uint64(int(step["reward_bits"])), where
            assert (terminated, truncated) == (step["terminated"], step["truncated"]), where
            assert info.get("success") == step["success"], where
