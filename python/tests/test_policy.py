"""A policy trained by the real binaries (tests/tests/python.rs): the exported bundle, the bare
checkpoint and the run directory load as the same module; the module gives the Rust actor's
actions; ONNX gives the module's; the policy plays Gymnasium's own Pendulum-v1 as well as the
run measured; bad bundles are one-line errors."""

import csv
import json
import math
import os
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import onnxruntime as ort
import pytest
import torch

import selkd

RUN = Path(os.environ.get("SELKD_TEST_RUN", ""))
BUNDLE = Path(os.environ.get("SELKD_TEST_BUNDLE", ""))
CASES = json.load(open(os.environ["SELKD_TEST_ACTIONS"])) if "SELKD_TEST_ACTIONS" in os.environ else []


def test_the_module_gives_the_rust_actors_actions():
    policy = selkd.load_policy(BUNDLE)
    assert isinstance(policy, torch.nn.Module) and not policy.training
    obs = torch.tensor([c["obs"] for c in CASES])
    want = torch.tensor([c["action"] for c in CASES])
    with torch.no_grad():
        got = policy(obs)
    assert got.shape == want.shape
    assert (got - want).abs().max().item() <= 1e-6
    # One observation without a batch dimension works too, and act() is the NumPy form.
    assert np.allclose(policy.act(CASES[0]["obs"]), CASES[0]["action"], atol=1e-6)


def test_bundle_checkpoint_and_run_load_the_same_actor():
    meta = json.loads((BUNDLE / "policy.json").read_text())
    for key in ["env", "env_options", "obs_dim", "act_dim", "hidden", "activation", "log_std_min",
                "log_std_max", "gymnasium_action_scale", "actor", "score", "config", "format_version"]:
        assert key in meta, key
    assert meta["env"] == "pendulum" and meta["activation"] == "relu"
    assert meta["gymnasium_action_scale"] == 2.0
    assert meta["actor"] == meta["best_actor"]
    bundle = selkd.load_policy(BUNDLE)
    checkpoint = selkd.load_policy(RUN / "checkpoints" / "final")
    run = selkd.load_policy(RUN)
    obs = torch.randn(32, 3)
    with torch.no_grad():
        for other in [checkpoint, run, selkd.load_policy(RUN, actor=meta["actor"])]:
            assert torch.equal(bundle(obs), other(obs))
            assert other.metadata["actor"] == meta["actor"]
        others = [i for i in range(meta["actors"]) if i != meta["actor"]]
        assert not torch.equal(bundle(obs), selkd.load_policy(RUN, actor=others[0])(obs))


def test_sample_draws_around_the_deterministic_action():
    policy = selkd.load_policy(BUNDLE)
    obs = torch.tensor(CASES[0]["obs"]).expand(4000, 3)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        a = policy.sample(obs, generator=g)
        mu, log_std = policy.mean_log_std(obs[:1])
    assert a.abs().max() <= 1
    # The pre-tanh draws have the head's mean and standard deviation.
    u = torch.atanh(a.clamp(-1 + 1e-6, 1 - 1e-6))
    assert abs(u.mean().item() - mu.item()) < 4 * log_std.exp().item() / math.sqrt(4000) + 1e-3
    assert abs(u.std().item() / log_std.exp().item() - 1) < 0.1


def test_onnx_gives_the_modules_actions():
    policy = selkd.load_policy(BUNDLE)
    session = ort.InferenceSession(str(BUNDLE / "policy.onnx"))
    obs = np.array([c["obs"] for c in CASES], np.float32)
    got = session.run(["action"], {"obs": obs})[0]
    with torch.no_grad():
        want = policy(torch.from_numpy(obs)).numpy()
    assert got.shape == want.shape and np.abs(got - want).max() <= 1e-5


def test_the_policy_plays_gymnasiums_own_pendulum_as_well_as_the_run_measured():
    policy = selkd.load_policy(BUNDLE)
    actor = policy.metadata["actor"]
    rows = list(csv.DictReader(open(RUN / "metrics.csv")))
    run_returns = [float(r[f"eval_return_{actor}"]) for r in rows[-3:]]
    env = gym.make("Pendulum-v1")
    returns = []
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            obs, r, terminated, truncated, _ = env.step(policy.act(obs) * policy.action_scale)
            total += r
            done = terminated or truncated
        returns.append(total)
    mean, sd = float(np.mean(returns)), float(np.std(returns, ddof=1))
    # The run's last three evaluations (3 episodes each), widened by two standard errors of a
    # 3-episode mean as Gymnasium's episodes spread.
    margin = 2 * sd / math.sqrt(3)
    lo, hi = min(run_returns) - margin, max(run_returns) + margin
    assert lo <= mean <= hi, f"Gymnasium {mean:.0f} ± {sd:.0f}; run {run_returns}, band [{lo:.0f}, {hi:.0f}]"
    assert mean > -400, f"a trained policy: {mean:.0f}"


def test_bad_bundles_are_one_line_errors(tmp_path):
    def error(path, **kw):
        with pytest.raises(selkd.SelkdError) as e:
            selkd.load_policy(path, **kw)
        assert "\n" not in str(e.value)
        return str(e.value)

    newer = tmp_path / "newer"
    shutil.copytree(BUNDLE, newer)
    meta = json.loads((newer / "policy.json").read_text())
    meta["format_version"] = 2
    (newer / "policy.json").write_text(json.dumps(meta))
    assert "bundle format 2 is newer than this selkd package reads (1)" in error(newer)
    assert "no such bundle" in error(tmp_path / "missing")
    assert "not a policy bundle" in error(tmp_path)
    assert "the checkpoint has 3 actors" in error(RUN, actor=9)
    assert "expected 'best' or an actor index" in error(RUN, actor="worst")
    assert "holds actor" in error(BUNDLE, actor=(meta["actor"] + 1) % 3)
    (newer / "policy.safetensors").write_bytes(b"\x01")
    meta["format_version"] = 1
    (newer / "policy.json").write_text(json.dumps(meta))
    assert "not a safetensors file" in error(newer)
