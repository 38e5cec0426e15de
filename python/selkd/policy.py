"""Trained actors as PyTorch modules.

``load_policy(path, actor="best")`` reads either a bundle written by ``selkd export`` (a
directory with ``policy.json`` and ``policy.safetensors``), a training checkpoint directory
(``RUN/checkpoints/NAME``, with ``state.json`` and ``model.safetensors``), or a run directory
(its latest checkpoint), and returns a ``SelkdPolicy``.

``python -m selkd.policy onnx DIR`` writes ``DIR/policy.onnx`` for a bundle (what
``selkd export --onnx`` runs).
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ._native import SelkdError

# The bundle format this package reads (``selkd export`` writes its FORMAT_VERSION).
FORMAT_VERSION = 1

_DTYPES = {"F32": np.float32, "F64": np.float64, "F16": np.float16, "BF16": None}


def read_safetensors(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of a safetensors file: an 8-byte header length, a JSON header, raw data."""
    data = Path(path).read_bytes()
    if len(data) < 8:
        raise SelkdError(f"{path}: not a safetensors file (too short)")
    (n,) = struct.unpack("<Q", data[:8])
    try:
        header = json.loads(data[8 : 8 + n])
    except ValueError:
        raise SelkdError(f"{path}: not a safetensors file (bad header)") from None
    out = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        lo, hi = info["data_offsets"]
        raw = data[8 + n + lo : 8 + n + hi]
        if info["dtype"] == "BF16":
            # bf16 is the top half of a float32.
            words = np.frombuffer(raw, dtype=np.uint16).astype(np.uint32) << 16
            array = words.view(np.float32)
        elif info["dtype"] in _DTYPES:
            array = np.frombuffer(raw, dtype=_DTYPES[info["dtype"]])
        else:
            raise SelkdError(f"{path}: tensor {name} has dtype {info['dtype']}, not a float")
        out[name] = torch.from_numpy(array.astype(np.float32).reshape(info["shape"]))
    return out


class SelkdPolicy(nn.Module):
    """An SELKD actor: ``obs → Linear → ReLU → … → Linear → [μ, log σ]``.

    ``forward(obs)`` is the deterministic action ``tanh(μ)`` (what evaluation plays), in
    ``[-1, 1]``; ``env_action(obs)`` is that action in the Gymnasium env's own units (the
    Box's bounds for a ``gymnasium:`` run; ``action_scale × forward(obs)`` for our envs' twins).
    ``sample(obs)`` draws the stochastic action ``tanh(μ + σ·ε)``. ``metadata`` holds the
    bundle's ``policy.json``.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: list[int],
                 log_std_min: float = -20.0, log_std_max: float = 2.0,
                 metadata: dict[str, Any] | None = None):
        super().__init__()
        dims = [obs_dim, *hidden, 2 * act_dim]
        layers: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
            layers.append(nn.Linear(a, b))
            if i + 2 < len(dims):
                layers.append(nn.ReLU())
        self.net = nn.Sequential(*layers)
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.log_std_min, self.log_std_max = log_std_min, log_std_max
        self.metadata = dict(metadata or {})
        self.action_scale = float(self.metadata.get("gymnasium_action_scale", 1.0))

    def mean_log_std(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(obs)
        mu, log_std = out[..., : self.act_dim], out[..., self.act_dim :]
        return mu, log_std.clamp(self.log_std_min, self.log_std_max)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.mean_log_std(obs)[0])

    def sample(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        mu, log_std = self.mean_log_std(obs)
        eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
        return torch.tanh(mu + log_std.exp() * eps)

    def act(self, obs) -> np.ndarray:
        """The deterministic action for one NumPy observation, as NumPy (for an env loop)."""
        with torch.no_grad():
            return self(torch.as_tensor(np.asarray(obs, dtype=np.float32))).numpy()

    def env_action(self, obs) -> np.ndarray:
        """``act(obs)`` in the Gymnasium env's own units, as the workers step it: mapped
        affinely from [-1, 1] onto the action Box of a ``gymnasium:`` run, else scaled by
        ``action_scale`` (our envs' Gymnasium twins take ±``action_scale``)."""
        a = self.act(obs)
        if "action_low" in self.metadata:
            # In float64, as the workers map it before Gymnasium's step.
            a64 = np.clip(a.astype(np.float64), -1.0, 1.0).reshape(-1)
            low = np.asarray(self.metadata["action_low"], dtype=np.float64)
            high = np.asarray(self.metadata["action_high"], dtype=np.float64)
            return (low + (a64 + 1.0) * 0.5 * (high - low)).reshape(a.shape)
        return self.action_scale * a


def _bundle(path: Path) -> SelkdPolicy:
    meta = json.loads((path / "policy.json").read_text())
    if meta.get("format") != "selkd-policy":
        raise SelkdError(f"{path}/policy.json: not a selkd policy bundle (format {meta.get('format')!r})")
    version = meta.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise SelkdError(
            f"{path}: bundle format {version} is newer than this selkd package reads "
            f"({FORMAT_VERSION}); update the package (bash deploy/python.sh)"
        )
    if meta.get("activation") != "relu" or meta.get("squash") != "tanh":
        raise SelkdError(
            f"{path}: activation {meta.get('activation')!r} and squash {meta.get('squash')!r} "
            f"are not what this package builds (relu, tanh)"
        )
    policy = SelkdPolicy(meta["obs_dim"], meta["act_dim"], meta["hidden"],
                         meta["log_std_min"], meta["log_std_max"], meta)
    policy.load_state_dict(read_safetensors(path / "policy.safetensors"))
    return policy.eval()


def _latest_checkpoint(run: Path) -> Path:
    d = run / "checkpoints"
    latest = d / "latest"
    names = [latest.read_text().strip()] if latest.exists() else []
    for name in [*names, "final"]:
        if (d / name / "state.json").exists():
            return d / name
    raise SelkdError(f"{run}: the run has no checkpoint yet (no checkpoints/latest or final)")


def _checkpoint(path: Path, actor: str | int) -> SelkdPolicy:
    from ._native import Env

    state = json.loads((path / "state.json").read_text())
    tensors = read_safetensors(path / "model.safetensors")
    layers = []
    while f"actors.{len(layers)}.weight" in tensors:
        l = len(layers)
        layers.append((tensors[f"actors.{l}.weight"], tensors[f"actors.{l}.bias"]))
    if not layers:
        raise SelkdError(f"{path}/model.safetensors holds no actor (no tensor actors.0.weight)")
    k = layers[0][0].shape[0]
    scores = _scores(state["ranking"])
    cfg = state["config"]
    # AVTD: the actors are the variants, of which the selected one acts (and holds the score).
    avtd = bool(cfg["algo"].get("variants"))
    best = state.get("selected_variant", 0) if avtd else _best(scores)
    index = best if actor == "best" else int(actor)
    if not 0 <= index < k:
        raise SelkdError(f"actor {actor}: the checkpoint has {k} actors (0 to {k - 1})")
    score = (scores[0] if index == best else None) if avtd else scores[index]
    obs_dim = layers[0][0].shape[1]
    act_dim = layers[-1][0].shape[2] // 2
    hidden = [w.shape[2] for w, _ in layers[:-1]]
    env = cfg["run"]["env"]
    options = cfg.get("env_options", {})
    if env.startswith(GYMNASIUM_PREFIX):
        low, high = _gymnasium_action_bounds(env[len(GYMNASIUM_PREFIX):], options)
        scale = _symmetric_scale(low, high)
        bounds = {"action_low": low, "action_high": high}
    else:
        # This package's own envs; their Gymnasium twins take ±scale.
        scale = Env(env, json.dumps(options)).spec.gymnasium_action_scale
        bounds = {}
    meta = {"format": "selkd-policy", "format_version": FORMAT_VERSION, "env": env,
            "env_options": options, "gymnasium_action_scale": scale, **bounds,
            "obs_dim": obs_dim, "act_dim": act_dim, "hidden": hidden, "activation": "relu",
            "log_std_min": -20.0, "log_std_max": 2.0, "squash": "tanh", "actor": index,
            "actors": k, "best_actor": best, "score": score, "scores": scores,
            "env_steps": sum(state["received"]), "checkpoint": str(path.resolve()), "config": cfg}
    policy = SelkdPolicy(obs_dim, act_dim, hidden, metadata=meta)
    sd = {}
    for l, (w, b) in enumerate(layers):
        sd[f"net.{2 * l}.weight"] = w[index].T.contiguous()  # [in, out] → nn.Linear's [out, in]
        sd[f"net.{2 * l}.bias"] = b[index].reshape(-1)
    policy.load_state_dict(sd)
    return policy.eval()


GYMNASIUM_PREFIX = "gymnasium:"


def _gymnasium_action_bounds(env_id: str, options: dict) -> tuple[list[float], list[float]]:
    """The flattened action Box of a ``gymnasium:`` run's env, made as the workers make it:
    ``options`` are ``gymnasium.make``'s keywords but ``import``, modules imported first."""
    import importlib

    try:
        import gymnasium
    except ImportError:
        raise SelkdError(f"gymnasium:{env_id}: this Python has no gymnasium; pip install gymnasium") from None
    kwargs = dict(options)
    for module in kwargs.pop("import", []):
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise SelkdError(f"gymnasium:{env_id}: importing {module!r} ({e}): install it") from None
    try:
        env = gymnasium.make(env_id, **kwargs)
    except Exception as e:  # Gymnasium's own message names the near miss or the bad keyword.
        raise SelkdError(f"gymnasium:{env_id}: {type(e).__name__}: {e}") from None
    try:
        space = env.action_space
        if not isinstance(space, gymnasium.spaces.Box):
            raise SelkdError(f"gymnasium:{env_id}: the action space is {space}, not a Box")
        low = np.asarray(space.low, dtype=np.float64).ravel()
        high = np.asarray(space.high, dtype=np.float64).ravel()
    finally:
        env.close()
    return low.tolist(), high.tolist()


def _symmetric_scale(low: list[float], high: list[float]) -> float:
    """As the workers' spec: c when the Box is ±c in every dimension, else NaN (no one scale)."""
    symmetric = all(abs(l + h) < 1e-9 for l, h in zip(low, high))
    same = all(abs(h - high[0]) <= 1e-9 * max(abs(h), 1.0) for h in high)
    return float(high[0]) if high and symmetric and same else float("nan")


def _scores(ranking: dict) -> list[float | None]:
    # As the learner's Ranking::scores: the last evaluation, else the mean of recent training
    # returns, else none.
    out = []
    for e, t in zip(ranking["evaluation"], ranking["training"]):
        out.append(e if e is not None else (sum(t) / len(t) if t else None))
    return out


def _best(scores: list[float | None]) -> int:
    best = None
    for i, s in enumerate(scores):
        if s is not None and (best is None or s > scores[best]):
            best = i
    return 0 if best is None else best


def load_policy(path, actor: str | int = "best") -> SelkdPolicy:
    """The actor at ``path`` (a bundle, a checkpoint directory or a run directory) as a module
    in eval mode. ``actor``: ``"best"`` (by the checkpoint's ranking) or an index; a bundle holds
    one actor and takes only ``"best"`` or its own index."""
    p = Path(path)
    if not p.exists():
        raise SelkdError(f"{p}: no such bundle, checkpoint or run directory")
    if actor != "best" and not (isinstance(actor, int) or str(actor).isdigit()):
        raise SelkdError(f"actor {actor!r}: expected 'best' or an actor index")
    if (p / "policy.json").exists():
        policy = _bundle(p)
        if actor != "best" and int(actor) != policy.metadata["actor"]:
            raise SelkdError(
                f"{p} holds actor {policy.metadata['actor']} only; export actor {actor} "
                f"(selkd export --actor {actor}) or load the checkpoint"
            )
        return policy
    if (p / "config.toml").exists() and not (p / "state.json").exists():
        p = _latest_checkpoint(p)
    if (p / "state.json").exists():
        return _checkpoint(p, actor)
    raise SelkdError(
        f"{p}: not a policy bundle (policy.json), a checkpoint (state.json) or a run (config.toml)"
    )


def export_onnx(path, out=None) -> Path:
    """Writes the deterministic action of the policy at ``path`` as ONNX (input ``obs``
    ``[batch, obs_dim]``, output ``action`` ``[batch, act_dim]``); default ``path/policy.onnx``."""
    policy = load_policy(path)
    out = Path(out) if out is not None else Path(path) / "policy.onnx"
    example = torch.zeros(1, policy.obs_dim)
    torch.onnx.export(policy, (example,), str(out), input_names=["obs"], output_names=["action"],
                      dynamic_axes={"obs": {0: "batch"}, "action": {0: "batch"}}, dynamo=False)
    return out


def _main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] != "onnx":
        print("usage: python -m selkd.policy onnx BUNDLE_DIR", file=sys.stderr)
        return 2
    try:
        out = export_onnx(argv[1])
    except SelkdError as e:
        print(f"selkd: error: {e}", file=sys.stderr)
        return 2
    print(f"selkd: wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
