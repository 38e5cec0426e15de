"""A policy trained by the real binaries on a ``gymnasium:`` env (tests/tests/gymnasium.rs):
``load_policy`` of the run reads the env's action Box from Gymnasium, and the loaded module,
stepped here through ``env_action``, plays the episodes ``selkd eval`` played on the same seeds."""

import json
import math
import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import selkd
import selkd_test_gym  # noqa: F401  (registers SelkdEcho-v0)

RUN = Path(os.environ.get("SELKD_TEST_RUN", ""))
EVAL = Path(os.environ.get("SELKD_TEST_EVAL", ""))


def test_a_gymnasium_run_loads_with_its_box_and_replays_selkd_eval():
    policy = selkd.load_policy(RUN)
    meta = policy.metadata
    assert meta["env"] == "gymnasium:SelkdEcho-v0"
    assert meta["action_low"] == [-2.0, 0.0] and meta["action_high"] == [2.0, 1.0]
    # No one number maps [-1, 1] onto [-2, 2] x [0, 1].
    assert math.isnan(meta["gymnasium_action_scale"])
    evaluation = json.loads(EVAL.read_text())
    best = evaluation["actors"][0]
    assert meta["actor"] == best["actor"]
    env = gym.make("SelkdEcho-v0")
    for seed, want in zip(evaluation["seeds"], best["returns"], strict=True):
        obs, _ = env.reset(seed=seed)
        total, done, steps = 0.0, False, 0
        while not done:
            a = policy.env_action(obs.reshape(-1))
            # The affine map, written out: -1 → low, 1 → high.
            expect = np.array([-2.0, 0.0]) + (np.clip(policy.act(obs.reshape(-1)), -1, 1) + 1) / 2 * np.array([4.0, 1.0])
            assert np.allclose(a, expect, atol=1e-6)
            obs, reward, terminated, truncated, _ = env.step(a)
            # The env echoes the action it was given.
            assert np.array_equal(obs.reshape(-1)[:2], a)
            total += reward
            steps += 1
            done = terminated or truncated
        assert steps == 50
        assert total == pytest.approx(want, rel=1e-4, abs=1e-4), (seed, total, want)


def test_an_unknown_gymnasium_id_is_one_selkd_error(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    src = RUN / "checkpoints" / (RUN / "checkpoints" / "latest").read_text().strip()
    ckpt = run / "checkpoints" / "final"
    ckpt.mkdir()
    state = json.loads((src / "state.json").read_text())
    state["config"]["run"]["env"] = "gymnasium:SelkdEhco-v0"
    (ckpt / "state.json").write_text(json.dumps(state))
    (ckpt / "model.safetensors").write_bytes((src / "model.safetensors").read_bytes())
    (run / "config.toml").write_text("")
    with pytest.raises(selkd.SelkdError, match="SelkdEhco-v0"):
        selkd.load_policy(run)
