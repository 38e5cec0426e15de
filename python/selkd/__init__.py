"""SELKD from Python: the tasks as Gymnasium environments and trained policies as PyTorch modules.

    import gymnasium as gym
    import selkd                                    # registers selkd/Hopper-v0, ...
    env = gym.make("selkd/Hopper-v0")               # or gym.make_vec(..., num_envs=8)
    policy = selkd.load_policy("runs/NAME/export")  # a torch.nn.Module: forward(obs) = tanh(mu)

``load_policy`` and ``export_onnx`` import torch when called; the envs need only NumPy.
"""

from ._native import SelkdError, names
from .envs import SelkdEnv, SelkdVectorEnv, gymnasium_id, register_all

register_all()


def load_policy(path, actor="best"):
    """A trained actor as a ``torch.nn.Module`` (see ``selkd.policy.load_policy``)."""
    from .policy import load_policy as load

    return load(path, actor)


def export_onnx(path, out=None):
    """Writes an exported bundle's policy as ONNX (see ``selkd.policy.export_onnx``)."""
    from .policy import export_onnx as export

    return export(path, out)


__all__ = [
    "SelkdError",
    "SelkdEnv",
    "SelkdVectorEnv",
    "export_onnx",
    "gymnasium_id",
    "load_policy",
    "names",
    "register_all",
]
