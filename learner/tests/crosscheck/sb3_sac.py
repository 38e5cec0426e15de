"""Our SAC against Stable-Baselines3's own `SAC.train`, update by update.

Usage: sb3_sac.py CASE.json  (written by learner/tests/crosscheck.rs, run in the project's venv,
which deploy/python.sh makes with stable-baselines3==2.9.2)

The case is the learner's SAC (K = 1, N = M = 2, the actor on min(Q1, Q2), one learning rate) run
for two rounds with every draw recorded, as round.py reads it. Here nothing is re-implemented:
for every update, SB3's SAC takes the learner's state from before it (weights, target critics,
log α, every Adam moment and step) and runs one step of its own `train`, with its replay buffer
made to return the learner's mini-batch and torch's Gaussian draws made to return the learner's
noise. SB3 does α, critic, actor and Polyak in one step on one batch, where the learner updates
the critics (and their targets) on one batch and the actor and α on another, so each update is
checked on the parts it changes:

- a critic update: SB3's critics, target critics and the critics' Adam moments after its step
  (its target uses α before its α step, as the learner's does; its actor and α steps are ignored);
- an actor update: SB3's actor, log α and their Adam moments after its step, its critics held
  still (learning rate 0), so that its actor sees the critics the learner's did.

Tolerances are looser than round.py's: SB3 corrects the tanh's log-density with log(1 − a² + 1e-6)
where the learner uses the exact log(1 − tanh(u)²). A wrong formula moves a moment by O(1) of its
size; this comparison allows 1e-3 of a tensor's largest entry: of the moments, and of each weight's
step in this update (after − before), plus, for weights, the difference of the two sides' Adam
steps (round.py's allowance) and, for the target critics, (1 − ρ) times the critics' difference
and a few ulps of the weight (a Polyak step is ~1e-5 of a weight near 0.3, a few ulps of it). Exit status 0 iff every update agrees.
"""

import json
import sys
import warnings

warnings.filterwarnings("ignore")
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import SAC  # noqa: E402
from stable_baselines3.common.logger import configure  # noqa: E402
from stable_baselines3.common.type_aliases import ReplayBufferSamples  # noqa: E402

torch.set_num_threads(1)
TOL = 1e-3


def tensor(v):
    return torch.tensor(v["data"], dtype=torch.float64).to(torch.float32).reshape(v["shape"])


class Spaces(gym.Env):
    """An env that only has the case's spaces: SB3 builds its networks from them."""

    def __init__(self, obs_dim, act_dim):
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (act_dim,), np.float32)

    def reset(self, seed=None, options=None):
        return np.zeros(self.observation_space.shape, np.float32), {}

    def step(self, action):
        return np.zeros(self.observation_space.shape, np.float32), 0.0, False, False, {}


def linears(seq):
    return [m for m in seq if isinstance(m, torch.nn.Linear)]


class Sb3:
    def __init__(self, case):
        c = case["cfg"]
        assert c["actors"] == 1 and c["critics"] == 2 and c["subset"] == 2 and c["actor_q"] == "min"
        assert c["lr"] == c["alpha_lr"], "SB3's SAC has one learning rate"
        self.A = case["act_dim"]
        self.cfg = c
        self.model = SAC(
            "MlpPolicy", Spaces(case["obs_dim"], case["act_dim"]), learning_rate=c["lr"],
            batch_size=c["batch_size"], tau=1 - c["polyak"], gamma=c["gamma"], ent_coef="auto",
            target_entropy="auto", learning_starts=0, policy_kwargs=dict(net_arch=c["hidden"]),
            device="cpu", seed=0,
        )
        self.model.set_logger(configure(None, []))
        # Learning rates are set here per update, not by SB3's schedule.
        self.model._update_learning_rate = lambda optimizers: None
        p = self.model.policy
        # Learner layer n (per member) ↔ SB3 module, in the learner's order.
        self.actor_layers = linears(p.actor.latent_pi) + [(p.actor.mu, p.actor.log_std)]
        self.critic_layers = [linears(q) for q in p.critic.q_networks]
        self.target_layers = [linears(q) for q in p.critic_target.q_networks]
        self.noise = []
        model = self.model
        outer = self

        def rsample(dist, sample_shape=torch.Size()):
            eps = outer.noise.pop(0)
            assert eps.shape == dist.loc.shape, f"noise {tuple(eps.shape)} for {tuple(dist.loc.shape)}"
            return dist.loc + eps * dist.scale

        torch.distributions.Normal.rsample = rsample
        model.replay_buffer.sample = lambda batch_size, env=None: outer.batch

    # --- the learner's layout ([E, in, out] weights, [E, 1, out] biases) onto SB3's modules ---

    def actor_params(self, take):
        """(SB3 parameter, learner tensor) pairs for the actor: the last layer's 2A outputs are
        SB3's mu (first A) and log_std (last A)."""
        out = []
        for n, layer in enumerate(self.actor_layers):
            w, b = take(n, "weight")[0], take(n, "bias")[0].reshape(-1)
            if isinstance(layer, tuple):
                mu, log_std = layer
                out += [(mu.weight, w[:, : self.A].T), (mu.bias, b[: self.A]),
                        (log_std.weight, w[:, self.A :].T), (log_std.bias, b[self.A :])]
            else:
                out += [(layer.weight, w.T), (layer.bias, b)]
        return out

    def critic_params(self, layers, take):
        out = []
        for j, net in enumerate(layers):
            for n, lin in enumerate(net):
                out += [(lin.weight, take(n, "weight")[j].T), (lin.bias, take(n, "bias")[j].reshape(-1))]
        return out

    @staticmethod
    def weights(st, key):
        return lambda n, kind: tensor(st[key][n][kind])

    @staticmethod
    def moments(st, opt, which):
        # The learner's moments are listed per parameter in layer order: weight, bias, weight, ...
        return lambda n, kind: tensor(st[opt][which][2 * n + (kind == "bias")])

    def load(self, st):
        p = self.model.policy
        with torch.no_grad():
            for param, value in (self.actor_params(self.weights(st, "actors"))
                                 + self.critic_params(self.critic_layers, self.weights(st, "critics"))
                                 + self.critic_params(self.target_layers, self.weights(st, "target_critics"))):
                assert param.shape == value.shape, (param.shape, value.shape)
                param.copy_(value)
            self.model.log_ent_coef.copy_(tensor(st["log_alpha"]).reshape(1))
        for opt, name, pairs in [
            (p.actor.optimizer, "actor_opt", lambda w: self.actor_params(w)),
            (p.critic.optimizer, "critic_opt", lambda w: self.critic_params(self.critic_layers, w)),
        ]:
            opt.state.clear()
            step = st[name]["step"]
            if step == 0:
                continue
            m = pairs(self.moments(st, name, "exp_avg"))
            v = pairs(self.moments(st, name, "exp_avg_sq"))
            for (param, mt), (_, vt) in zip(m, v):
                opt.state[param] = {"step": torch.tensor(float(step)), "exp_avg": mt.clone(), "exp_avg_sq": vt.clone()}
        opt = self.model.ent_coef_optimizer
        opt.state.clear()
        a = st["alpha_opt"]
        if a["step"] > 0:
            opt.state[self.model.log_ent_coef] = {
                "step": torch.tensor(float(a["step"])),
                "exp_avg": tensor(a["exp_avg"][0]).reshape(1).clone(),
                "exp_avg_sq": tensor(a["exp_avg_sq"][0]).reshape(1).clone(),
            }

    def step(self, b, noise, critic_lr):
        """One step of SB3's own train() on mini-batch b (the learner's, group 0) and noise."""
        take = lambda k: tensor(b[k])[0]  # noqa: E731
        self.batch = ReplayBufferSamples(
            observations=take("obs"), actions=take("act"), next_observations=take("next_obs"),
            dones=take("terminated").reshape(-1, 1), rewards=take("reward").reshape(-1, 1),
            discounts=None,
        )
        self.noise = list(noise)
        p = self.model.policy
        for opt, lr in [(p.actor.optimizer, self.cfg["lr"]), (p.critic.optimizer, critic_lr),
                        (self.model.ent_coef_optimizer, self.cfg["lr"])]:
            for g in opt.param_groups:
                g["lr"] = lr
        self.model.train(gradient_steps=1, batch_size=self.cfg["batch_size"])
        assert not self.noise, "SB3 drew less noise than the learner's update"


def adam_ratio(m, v, step):
    m, v = m.double(), v.double()
    return (m / (1 - 0.9 ** step)) / ((v / (1 - 0.999 ** step)).sqrt() + 1e-8)


def main():
    case = json.load(open(sys.argv[1]))
    sb3 = Sb3(case)
    c = case["cfg"]
    B, A = c["batch_size"], case["act_dim"]
    zeros = torch.zeros(B, A)
    failures, worst = [], {}

    def compare(what, got, want, allow=None):
        got, want = got.double(), want.double()
        scale = want.abs().max().item()
        tol = TOL * scale + (0.0 if allow is None else allow)
        err = (got - want).abs()
        worst[what.split("[")[0]] = max(worst.get(what.split("[")[0], 0.0), (err.max().item() / scale) if scale else 0.0)
        if (err > tol).any():
            k = int((err > tol).reshape(-1).nonzero()[0])
            failures.append(f"{what}: {int((err > tol).sum())} of {err.numel()} entries differ, e.g. "
                            f"learner {want.reshape(-1)[k].item():.7g} vs SB3 {got.reshape(-1)[k].item():.7g}")

    def compare_opt(where, opt, pairs_w, pairs_w0, pairs_m, pairs_v, step, lr):
        """Both moments, and each weight's step (after − before, so that the tolerance is a
        fraction of a step, not of the weight) with the Adam allowance, SB3's against the
        learner's. Returns SB3's weights minus the learner's."""
        diffs = []
        for i, ((param, w), (_, w0), (_, m), (_, v)) in enumerate(zip(pairs_w, pairs_w0, pairs_m, pairs_v)):
            st = opt.state[param]
            compare(f"exp_avg[{i}, {where}]", st["exp_avg"], m)
            compare(f"exp_avg_sq[{i}, {where}]", st["exp_avg_sq"], v)
            allow = 2 * lr * (adam_ratio(st["exp_avg"], st["exp_avg_sq"], step) - adam_ratio(m, v, step)).abs()
            compare(f"weight step[{i}, {where}]", param.detach() - w0, w - w0, allow)
            diffs.append((param.detach() - w).abs())
        return diffs

    p = sb3.model.policy
    before = case["initial"]
    moved = False
    for u, upd in enumerate(case["updates"]):
        where = f"update {u + 1} ({upd['kind']})"
        after = upd["state"]
        sb3.load(before)
        d = {x["kind"]: x for x in upd["draws"]}
        eps = tensor(d["normal"]["value"])[0]  # [B, A]: K = 1, one group
        if upd["kind"] == "critic":
            # SB3 samples the actor on s (for α and the actor: not compared here), then on s'.
            sb3.step(d["critic_batch"]["batch"], [zeros, eps], c["lr"])
            step = after["critic_opt"]["step"]
            diffs = compare_opt(where, p.critic.optimizer,
                        sb3.critic_params(sb3.critic_layers, sb3.weights(after, "critics")),
                        sb3.critic_params(sb3.critic_layers, sb3.weights(before, "critics")),
                        sb3.critic_params(sb3.critic_layers, sb3.moments(after, "critic_opt", "exp_avg")),
                        sb3.critic_params(sb3.critic_layers, sb3.moments(after, "critic_opt", "exp_avg_sq")),
                        step, c["lr"])
            # The targets' Polyak step: (1 − ρ)·(critic − target), so SB3's may differ by (1 − ρ)
            # times the difference of the two sides' critics, which was just compared.
            targets = zip(sb3.critic_params(sb3.target_layers, sb3.weights(after, "target_critics")),
                          sb3.critic_params(sb3.target_layers, sb3.weights(before, "target_critics")), diffs)
            for i, ((param, w), (_, w0), diff) in enumerate(targets):
                # ... and by the float32 round-off of the weight it is added to (a few ulps).
                ulps = 4 * torch.finfo(torch.float32).eps * w.abs()
                compare(f"target step[{i}, {where}]", param.detach() - w0, w - w0, (1 - c["polyak"]) * diff + ulps)
        else:
            batch = d["actor_batch"]["batch"]
            sb3.step(batch, [eps, zeros], 0.0)
            step = after["actor_opt"]["step"]
            compare_opt(where, p.actor.optimizer,
                        sb3.actor_params(sb3.weights(after, "actors")),
                        sb3.actor_params(sb3.weights(before, "actors")),
                        sb3.actor_params(sb3.moments(after, "actor_opt", "exp_avg")),
                        sb3.actor_params(sb3.moments(after, "actor_opt", "exp_avg_sq")),
                        step, c["lr"])
            a = after["alpha_opt"]
            st = sb3.model.ent_coef_optimizer.state[sb3.model.log_ent_coef]
            m, v = tensor(a["exp_avg"][0]).reshape(1), tensor(a["exp_avg_sq"][0]).reshape(1)
            compare(f"alpha exp_avg[{where}]", st["exp_avg"], m)
            allow = 2 * c["lr"] * (adam_ratio(st["exp_avg"], st["exp_avg_sq"], a["step"]) - adam_ratio(m, v, a["step"])).abs()
            a0 = tensor(before["log_alpha"]).reshape(1)
            compare(f"log_alpha step[{where}]", sb3.model.log_ent_coef.detach() - a0, tensor(after["log_alpha"]).reshape(1) - a0, allow)
            moved = True
        before = after
    assert moved, "the case has no actor update"
    print("SB3 SAC.train against the learner, " + ", ".join(f"max |error| / largest entry {v:.1e} ({k})" for k, v in sorted(worst.items())))
    for f in failures[:10]:
        print(f"  MISMATCH {f}")
    if failures:
        print(f"{len(failures)} comparisons disagree")
        sys.exit(1)
    print(f"{len(case['updates'])} updates agree with Stable-Baselines3 {__import__('stable_baselines3').__version__}")


if __name__ == "__main__":
    main()
