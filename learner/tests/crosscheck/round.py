"""SPEC.md's training round, written again in PyTorch, to check the Rust learner against.

Usage: round.py CASES.json  (written by learner/tests/crosscheck.rs)

Each case holds a configuration, the learner's initial state, and its two rounds as a list of
updates (G critic updates, then the actor update, per round); each update has every random draw
the learner made for it (mini-batches, critic subsets, Gaussian noise, REM's uniform draws), the
learner's reported losses and its state afterwards. This script builds its own networks (one
torch.nn.Sequential per actor and critic, torch.optim.Adam, torch.distributions) and, for every
update, loads the learner's state from before it, performs SPEC.md's update on the same draws,
and compares the result. It shares no code with the learner: only the data layout of the draws
(documented where they are used) is common. Exit status 0 iff every case agrees and trained.
"""

import json
import sys
import warnings

warnings.filterwarnings("ignore", message="Failed to initialize NumPy")
import torch  # noqa: E402
from torch import nn  # noqa: E402
from torch.distributions import Normal, kl_divergence  # noqa: E402
from torch.distributions.transforms import TanhTransform  # noqa: E402

torch.set_num_threads(1)
torch.set_default_dtype(torch.float32)

# Tolerances. Both sides compute in float32, in different orders (batched matmuls and fused
# reductions there, one module per network here), so an entry agrees to a few ulps of the largest
# terms summed into it, not of itself. An entry passes if |learner − reference| ≤ RTOL·|reference|
# + ATOL_SCALE·max|reference tensor|. The absolute floor is for entries that are sums of
# cancelling terms (a nearly-zero gradient moment is known only to the round-off of its terms).
# Seen over every case and seed set: errors ≤ 1e-6 of the tensor's largest entry. A wrong formula
# moves a moment by O(1) of its size and a weight by O(lr), orders of magnitude above this.
#
# Weights get one more, exact, allowance: Adam steps by lr·m̂/(√v̂ + ε), which turns the round-off
# of a near-zero gradient into a step known only to lr·round-off/√v̂, up to a whole step. So a
# weight may also differ by 2·lr·|r_learner − r_reference|, r = m̂/(√v̂ + ε) computed (in float64)
# from each side's own moments, which are themselves compared at the tight tolerance above; the
# targets by (1 − ρ) of that. This is why each update starts from the learner's state: the
# allowance covers one Adam step, not what a loosened weight does to later updates.
RTOL = 1e-6
ATOL_SCALE = 2e-6

def tensor(v):
    return torch.tensor(v["data"], dtype=torch.float64).to(torch.float32).reshape(v["shape"])


class Draws:
    """The learner's draws of one round, consumed in the order SPEC.md's round needs them."""

    def __init__(self, draws):
        self.draws = list(draws)
        self.at = 0

    def take(self, kind):
        d = self.draws[self.at]
        assert d["kind"] == kind, f"draw {self.at}: expected {kind}, the learner drew {d['kind']}"
        self.at += 1
        return d

    def done(self):
        assert self.at == len(self.draws), f"{len(self.draws) - self.at} draws left unused"


def mlp(layers):
    """One network from the learner's stacked layer list, member already picked: weight [in, out]."""
    mods = []
    for n, (w, b) in enumerate(layers):
        lin = nn.Linear(w.shape[0], w.shape[1])
        with torch.no_grad():
            lin.weight.copy_(w.T)
            lin.bias.copy_(b.reshape(-1))
        mods.append(lin)
        if n < len(layers) - 1:
            mods.append(nn.ReLU())
    return nn.Sequential(*mods)


def members(stacked):
    """The stacked ensemble JSON ([E, in, out] weights, [E, 1, out] biases) as E networks."""
    ws = [(tensor(l["weight"]), tensor(l["bias"])) for l in stacked]
    count = ws[0][0].shape[0]
    return [mlp([(w[e], b[e]) for w, b in ws]) for e in range(count)]


def linears(nets):
    return [[m for m in net if isinstance(m, nn.Linear)] for net in nets]


def stack_params(nets):
    """Back to the learner's layout: per layer, weight [E, in, out] and bias [E, 1, out]."""
    out = []
    for layer in zip(*linears(nets)):
        out.append(torch.stack([m.weight.detach().T for m in layer]))
        out.append(torch.stack([m.bias.detach().reshape(1, -1) for m in layer]))
    return out


def stack_moments(opt, nets, key):
    """An optimiser's moments in the learner's layout (zeros before its first step)."""
    get = lambda p: opt.state[p][key] if p in opt.state else torch.zeros_like(p)  # noqa: E731
    out = []
    for layer in zip(*linears(nets)):
        out.append(torch.stack([get(m.weight).T for m in layer]))
        out.append(torch.stack([get(m.bias).reshape(1, -1) for m in layer]))
    return out


def polyak(target, online, rho):
    with torch.no_grad():
        for t, o in zip(target.parameters(), online.parameters()):
            t.mul_(rho).add_(o, alpha=1 - rho)


def adam_ratio(exp_avg, exp_avg_sq, step, betas=(0.9, 0.999), eps=1e-8):
    """Adam's step direction m̂/(√v̂ + ε), in float64."""
    m, v = exp_avg.double(), exp_avg_sq.double()
    return (m / (1 - betas[0] ** step)) / ((v / (1 - betas[1] ** step)).sqrt() + eps)


class Learner:
    def __init__(self, case):
        self.cfg = c = case["cfg"]
        self.A = case["act_dim"]
        self.K, self.N, self.M, self.B = c["actors"], c["critics"], c["subset"], c["batch_size"]
        self.td3 = c["backbone"] == "td3"
        init = case["initial"]
        self.actors = members(init["actors"])
        self.critics = members(init["critics"])
        # SPEC: target critics start as copies of the critics (the learner sends its own; they
        # must be equal, which is checked here rather than assumed).
        self.target_critics = members(init["target_critics"])
        for t, q in zip(self.target_critics, self.critics):
            for a, b in zip(t.parameters(), q.parameters()):
                assert torch.equal(a, b), "target critics must start equal to the critics"
        self.target_actors = members(init["target_actors"]) if self.td3 else None
        self.log_alpha = tensor(init["log_alpha"]).clone().requires_grad_(True)
        assert torch.equal(self.log_alpha.detach(), torch.zeros(self.K)), "log α starts at 0"
        adam = dict(betas=(0.9, 0.999), eps=1e-8)
        self.actor_opt = torch.optim.Adam([p for a in self.actors for p in a.parameters()], lr=c["lr"], **adam)
        self.critic_opt = torch.optim.Adam([p for q in self.critics for p in q.parameters()], lr=c["lr"], **adam)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=c["alpha_lr"], **adam)
        # Which actors had a loss term in some round (they must have moved).
        self.had_loss = [False] * self.K

    def alpha(self):
        if self.cfg["fixed_alpha"] is not None:
            return torch.full((self.K,), float(self.cfg["fixed_alpha"]))
        return self.log_alpha.detach().exp()

    def head(self, net, s):
        out = net(s)
        mu = out[..., : self.A]
        log_std = out[..., self.A :].clamp(-20.0, 2.0)
        return mu, log_std

    def sample(self, net, s, eps):
        """Reparameterised tanh-Gaussian sample and its log-density, via torch.distributions."""
        mu, log_std = self.head(net, s)
        std = log_std.exp()
        u = mu + std * eps
        a = torch.tanh(u)
        logp = Normal(mu, std).log_prob(u).sum(-1) - TanhTransform().log_abs_det_jacobian(u, a).sum(-1)
        return a, logp

    def next_action(self, i, s2, eps):
        """ã'_i for the target: SAC samples π_i; TD3 smooths the target actor's action."""
        if self.td3:
            mu, _ = self.head(self.target_actors[i], s2)
            c = self.cfg["target_noise_clip"]
            noise = (self.cfg["target_noise"] * eps).clamp(-c, c)
            return (torch.tanh(mu) + noise).clamp(-1.0, 1.0), torch.zeros(s2.shape[0])
        return self.sample(self.actors[i], s2, eps)

    def inner(self, qs, weights):
        """Reduction over the subset: qs is [M, B] (one actor); weights REM's row of M."""
        t = self.cfg["target"]
        if t in ("max-min", "min-min"):
            return qs.min(0).values
        if t in ("max-max", "min-max"):
            return qs.max(0).values
        if t == "max-mean":
            return qs.mean(0)
        if t == "max-rem":
            return (weights.reshape(-1, 1) * qs).sum(0)
        if t == "max-aqe":
            keep = qs.shape[0] - self.cfg["aqe_drop"]
            return torch.topk(qs, keep, dim=0, largest=False).values.mean(0)
        raise ValueError(t)

    def owned(self, i):
        """DPD: critic j belongs to actor j·K/N (N/K consecutive critics per actor)."""
        return [j for j in range(self.N) if j * self.K // self.N == i]

    def critic_update(self, draws):
        d = draws.take("critic_batch")
        b = {k: tensor(v) for k, v in d["batch"].items()}
        groups = b["obs"].shape[0]
        subsets = torch.tensor(d["subsets"]).reshape(groups, self.M).tolist()
        # Next-action noise: [K, groups·B, A], row g·B + r for group g, row r.
        eps = tensor(draws.take("normal")["value"])
        rem = None
        if self.cfg["target"] == "max-rem":
            u = tensor(draws.take("uniform")["value"]).reshape(groups, self.M)
            rem = u / u.sum(1, keepdim=True)  # a random convex mixture
        alpha, gamma = self.alpha(), self.cfg["gamma"]
        outer_max = self.cfg["target"] not in ("min-min", "min-max")
        y = []  # per critic j
        with torch.no_grad():
            if self.cfg["paired_critics"]:
                r, done, s2 = b["reward"][0], b["terminated"][0], b["next_obs"][0]
                values = []
                for i in range(self.K):
                    a2, logp2 = self.next_action(i, s2, eps[i, : self.B])
                    x2 = torch.cat([s2, a2], -1)
                    q = torch.stack([self.target_critics[j](x2).squeeze(-1) for j in self.owned(i)])
                    values.append(q.min(0).values - alpha[i] * logp2)
                for j in range(self.N):
                    y.append(r + gamma * (1 - done) * values[j * self.K // self.N])
            else:
                per_group = []
                for g in range(groups):
                    r, done, s2 = b["reward"][g], b["terminated"][g], b["next_obs"][g]
                    v = []
                    for i in range(self.K):
                        a2, logp2 = self.next_action(i, s2, eps[i, g * self.B : (g + 1) * self.B])
                        x2 = torch.cat([s2, a2], -1)
                        qs = torch.stack([self.target_critics[m](x2).squeeze(-1) for m in subsets[g]])
                        v.append(self.inner(qs, None if rem is None else rem[g]) - alpha[i] * logp2)
                    v = torch.stack(v)
                    best = v.max(0).values if outer_max else v.min(0).values
                    per_group.append(r + gamma * (1 - done) * best)
                # per-update: one group for all critics; per-critic: critic j has group j.
                y = [per_group[j if groups > 1 else 0] for j in range(self.N)]
        self.critic_opt.zero_grad(set_to_none=True)
        losses, qmeans, qabs = [], [], []
        for j, critic in enumerate(self.critics):
            g = j if groups > 1 else 0
            q = critic(torch.cat([b["obs"][g], b["act"][g]], -1)).squeeze(-1)
            losses.append(0.5 * ((q - y[j]) ** 2).mean())
            qmeans.append(q.detach().mean())
            qabs.append(q.detach().abs().mean())
        # Σ_j J_Q_j: each critic's gradient is its own loss's.
        torch.stack(losses).sum().backward()
        self.critic_opt.step()
        for t, q in zip(self.target_critics, self.critics):
            polyak(t, q, self.cfg["polyak"])
        # The mean |Q| is the scale of q_mean's round-off (its terms may cancel).
        return torch.stack(losses).mean().item(), torch.stack(qmeans).mean().item(), torch.stack(qabs).mean().item()

    def actor_update(self, draws, best):
        d = draws.take("actor_batch")
        obs = tensor(d["batch"]["obs"])  # [K, B, obs]: actor i's own mini-batch
        eps = None if self.td3 else tensor(draws.take("normal")["value"])  # [K, B, A]
        alpha = self.alpha()
        for q in self.critics:
            q.requires_grad_(False)
        losses, kls, logps, scales = [], [], [], []
        for i in range(self.K):
            s = obs[i]
            if self.td3:
                mu, log_std = self.head(self.actors[i], s)
                a, logp = torch.tanh(mu), torch.zeros(self.B)
            else:
                mu, log_std = self.head(self.actors[i], s)
                a, logp = self.sample(self.actors[i], s, eps[i])
            judges = self.owned(i) if self.cfg["paired_critics"] else range(self.N)
            qs = torch.stack([self.critics[j](torch.cat([s, a], -1)).squeeze(-1) for j in judges])
            q = qs.mean(0) if self.cfg["actor_q"] == "mean" else qs.min(0).values
            ref = (i + 1) % self.K if self.cfg["paired_critics"] else best
            with torch.no_grad():
                mu_r, log_std_r = self.head(self.actors[ref], s)
            if self.td3:
                kl = ((a - torch.tanh(mu_r)) ** 2).mean(-1)  # SPEC 7.1: mean-squared action distance
            else:
                kl = kl_divergence(Normal(mu, log_std.exp()), Normal(mu_r, log_std_r.exp())).sum(-1)
            kd_actors = self.cfg["kd_actors"]
            distils = self.cfg["paired_critics"] or (i != best and (kd_actors is None or i in kd_actors))
            rl = not self.cfg["without_rl"] or i == 0
            loss = torch.zeros(())
            if rl:
                loss = loss + (alpha[i] * logp - q).mean()
            if distils and self.cfg["kd_weight"] != 0:
                loss = loss + self.cfg["kd_weight"] * kl.mean()
            self.had_loss[i] |= rl or (distils and self.cfg["kd_weight"] != 0)
            losses.append(loss)
            # The size of the loss's terms, the scale of its round-off (they may cancel).
            scales.append((alpha[i] * logp.abs() + q.abs() + self.cfg["kd_weight"] * kl.abs()).detach().mean().item())
            kls.append(kl.detach().mean())
            logps.append(logp.detach())
        for q in self.critics:
            q.requires_grad_(True)
        self.actor_opt.zero_grad(set_to_none=False)
        torch.stack(losses).sum().backward()
        # The project's convention: Adam steps every actor every round; one without a loss term
        # this round sees a zero gradient (its moments decay, its step count advances).
        for a in self.actors:
            for p in a.parameters():
                if p.grad is None:
                    p.grad = torch.zeros_like(p)
        self.actor_opt.step()
        if self.td3:
            for t, a in zip(self.target_actors, self.actors):
                polyak(t, a, self.cfg["polyak"])
        elif self.cfg["fixed_alpha"] is None:
            target_entropy = self.cfg["target_entropy"]
            if target_entropy is None:
                target_entropy = -float(self.A)
            lp = torch.stack(logps)  # [K, B]
            alpha_loss = -(self.log_alpha.reshape(-1, 1) * (lp + target_entropy)).mean(1).sum()
            self.alpha_opt.zero_grad()
            alpha_loss.backward()
            self.alpha_opt.step()
        return {
            "actor_loss": [l.item() for l in losses],
            "alpha": self.alpha().tolist(),
            "kl_to_best": [k.item() for k in kls],
            "entropy": [-lp.mean().item() for lp in logps],
            "scale": {"actor_loss": scales, "entropy": [lp.abs().mean().item() for lp in logps]},
        }

    def load(self, st):
        """Takes the learner's state (weights, targets, log α, Adam moments and steps) as its own."""
        with torch.no_grad():
            for key, nets in [("actors", self.actors), ("critics", self.critics),
                              ("target_critics", self.target_critics), ("target_actors", self.target_actors)]:
                if nets is None:
                    continue
                for n, layer in enumerate(zip(*linears(nets))):
                    w, b = tensor(st[key][n]["weight"]), tensor(st[key][n]["bias"])
                    for e, m in enumerate(layer):
                        m.weight.copy_(w[e].T)
                        m.bias.copy_(b[e].reshape(-1))
            self.log_alpha.copy_(tensor(st["log_alpha"]))
        for name, opt, params in [("actor_opt", self.actor_opt, self.layer_params(self.actors)),
                                  ("critic_opt", self.critic_opt, self.layer_params(self.critics)),
                                  ("alpha_opt", self.alpha_opt, [[self.log_alpha]])]:
            o = st[name]
            opt.state.clear()
            if o["step"] == 0:
                continue
            for n, members in enumerate(params):
                m, v = tensor(o["exp_avg"][n]), tensor(o["exp_avg_sq"][n])
                for e, p in enumerate(members):
                    shape = (lambda t: t.T) if p.dim() == 2 else (lambda t: t.reshape(p.shape))
                    pick = (lambda t: t) if name == "alpha_opt" else (lambda t: t[e])
                    opt.state[p] = {"step": torch.tensor(float(o["step"])),
                                    "exp_avg": shape(pick(m)).clone(), "exp_avg_sq": shape(pick(v)).clone()}

    @staticmethod
    def layer_params(nets):
        """Parameters in the learner's order (per layer: weight, bias), each a list over members."""
        out = []
        for layer in zip(*linears(nets)):
            out.append([m.weight for m in layer])
            out.append([m.bias for m in layer])
        return out

    def state(self):
        """This learner's state in the Rust learner's layout, as float32 tensors."""
        out = {
            "actors": stack_params(self.actors),
            "critics": stack_params(self.critics),
            "target_critics": stack_params(self.target_critics),
            "log_alpha": [self.log_alpha.detach()],
        }
        if self.td3:
            out["target_actors"] = stack_params(self.target_actors)
        for name, opt, nets in [("actor_opt", self.actor_opt, self.actors), ("critic_opt", self.critic_opt, self.critics)]:
            out[name + ".exp_avg"] = stack_moments(opt, nets, "exp_avg")
            out[name + ".exp_avg_sq"] = stack_moments(opt, nets, "exp_avg_sq")
        st = self.alpha_opt.state.get(self.log_alpha)
        if st:
            out["alpha_opt.exp_avg"] = [st["exp_avg"]]
            out["alpha_opt.exp_avg_sq"] = [st["exp_avg_sq"]]
        return out

    def steps(self):
        def step(opt):
            steps = {int(s["step"]) for s in opt.state.values()}
            assert len(steps) <= 1, f"parameters stepped unequally: {steps}"
            return steps.pop() if steps else 0

        return {"actor_opt": step(self.actor_opt), "critic_opt": step(self.critic_opt), "alpha_opt": step(self.alpha_opt)}


def rust_state(st):
    layers = lambda e: [tensor(l[k]) for l in e for k in ("weight", "bias")]  # noqa: E731
    out = {
        "actors": layers(st["actors"]),
        "critics": layers(st["critics"]),
        "target_critics": layers(st["target_critics"]),
        "log_alpha": [tensor(st["log_alpha"])],
    }
    if st["target_actors"] is not None:
        out["target_actors"] = layers(st["target_actors"])
    for name in ("actor_opt", "critic_opt", "alpha_opt"):
        if name == "alpha_opt" and st[name]["step"] == 0:
            continue
        out[name + ".exp_avg"] = [tensor(t) for t in st[name]["exp_avg"]]
        out[name + ".exp_avg_sq"] = [tensor(t) for t in st[name]["exp_avg_sq"]]
    return out


class Compare:
    def __init__(self):
        self.failures = []
        self.max_rel = {}  # quantity → max relative error (entries above 1e-3 of the largest)
        self.max_abs = {}  # quantity → max error / largest magnitude
        self.loose, self.entries = 0, 0  # weight entries whose tolerance the Adam allowance widens

    def values(self, what, got, want, allow=None, scale=None):
        got = torch.as_tensor(got, dtype=torch.float64)
        want = torch.as_tensor(want, dtype=torch.float64)
        if got.shape != want.shape:
            self.failures.append(f"{what}: shape {tuple(got.shape)} vs {tuple(want.shape)}")
            return
        if not torch.isfinite(got).all() or not torch.isfinite(want).all():
            self.failures.append(f"{what}: non-finite values")
            return
        scale = max([want.abs().max().item()] + ([] if scale is None else list(torch.as_tensor(scale).reshape(-1).tolist())))
        floor = ATOL_SCALE * scale
        err = (got - want).abs()
        tol = RTOL * want.abs() + floor
        if allow is not None:
            allow = torch.as_tensor(allow, dtype=torch.float64)
            self.loose += int((allow > floor).sum())
            self.entries += allow.numel()
            tol = tol + allow
        bad = err > tol
        above = want.abs() > 1e-3 * scale
        rel = (err[above] / want.abs()[above]).max().item() if above.any() else 0.0
        key = what.split("[")[0]
        self.max_rel[key] = max(self.max_rel.get(key, 0.0), rel)
        self.max_abs[key] = max(self.max_abs.get(key, 0.0), err.max().item() / scale if scale else 0.0)
        if bad.any():
            k = int(bad.reshape(-1).nonzero()[0])
            self.failures.append(
                f"{what}: {int(bad.sum())} of {bad.numel()} entries differ, e.g. learner "
                f"{got.reshape(-1)[k].item():.9g} vs reference {want.reshape(-1)[k].item():.9g}"
            )


def allowances(got, want, cfg, steps):
    """The Adam allowance of every weight (see the tolerances above), in the learner's layout."""
    out = {}
    for key, opt, lr in [("critics", "critic_opt", cfg["lr"]), ("actors", "actor_opt", cfg["lr"]),
                         ("log_alpha", "alpha_opt", cfg["alpha_lr"])]:
        if opt + ".exp_avg" not in got or opt + ".exp_avg" not in want:
            continue
        t = steps[opt]
        if t == 0:
            continue
        out[key] = [2 * lr * (adam_ratio(gm, gv, t) - adam_ratio(wm, wv, t)).abs()
                    for gm, gv, wm, wv in zip(got[opt + ".exp_avg"], got[opt + ".exp_avg_sq"],
                                              want[opt + ".exp_avg"], want[opt + ".exp_avg_sq"])]
    rho = cfg["polyak"]
    for target, online in [("target_critics", "critics"), ("target_actors", "actors")]:
        if online in out:
            out[target] = [(1 - rho) * a for a in out[online]]
    return out


def check_case(case):
    ref = Learner(case)
    cmp = Compare()
    cfg = case["cfg"]
    before = case["initial"]
    for u, upd in enumerate(case["updates"]):
        where = f"update {u + 1} ({upd['kind']})"
        ref.load(before)
        draws = Draws(upd["draws"])
        if upd["kind"] == "critic":
            loss, q, q_abs = ref.critic_update(draws)
            cmp.values(f"critic_loss[{where}]", upd["loss"], loss)
            cmp.values(f"q_mean[{where}]", upd["q_mean"], q, scale=q_abs)
        else:
            stats = ref.actor_update(draws, upd["best"])
            for k in ("actor_loss", "alpha", "kl_to_best", "entropy"):
                cmp.values(f"{k}[{where}]", upd["stats"][k], stats[k], scale=stats["scale"].get(k))
        draws.done()
        got, want = rust_state(upd["state"]), ref.state()
        steps = ref.steps()
        allow = allowances(got, want, cfg, steps)
        if set(got) != set(want):
            cmp.failures.append(f"{where}: state keys {sorted(got)} vs {sorted(want)}")
        for key in sorted(set(got) & set(want)):
            for n, (g, w) in enumerate(zip(got[key], want[key])):
                cmp.values(f"{key}[{n}, {where}]", g, w, allow[key][n] if key in allow else None)
        for name, step in steps.items():
            if upd["state"][name]["step"] != step:
                cmp.failures.append(f"{name}.step after {where}: {upd['state'][name]['step']} vs {step}")
        before = upd["state"]
    # It trained: each network with a loss moved well past round-off over the two rounds.
    initial, final = rust_state(case["initial"]), rust_state(case["updates"][-1]["state"])
    lr = cfg["lr"]
    moved = lambda key, e: max((f[e] - i[e]).abs().max().item() for f, i in zip(final[key], initial[key]))  # noqa: E731
    for key in [k for k in ("critics", "target_critics", "target_actors") if k in final]:
        for e in range(final[key][0].shape[0]):
            if moved(key, e) < 0.001 * lr:
                cmp.failures.append(f"{key} member {e} did not move")
    for e in range(ref.K):
        m = moved("actors", e)
        if ref.had_loss[e] and m < 0.1 * lr:
            cmp.failures.append(f"actor {e} had a loss but did not move ({m:g})")
        if not ref.had_loss[e] and m != 0.0:
            cmp.failures.append(f"actor {e} had no loss term but moved by {m:g}")
    auto_alpha = not ref.td3 and cfg["fixed_alpha"] is None
    alpha_moved = (final["log_alpha"][0] - initial["log_alpha"][0]).abs().min().item()
    if auto_alpha and alpha_moved < 0.5 * cfg["alpha_lr"]:
        cmp.failures.append(f"log α did not move ({alpha_moved:g})")
    if not auto_alpha and alpha_moved != 0.0:
        cmp.failures.append("log α moved although it is fixed")
    return cmp


def main():
    cases = json.load(open(sys.argv[1]))
    failed = 0
    for case in cases:
        try:
            cmp = check_case(case)
            failures, worst, wabs = cmp.failures, cmp.max_rel, cmp.max_abs
        except AssertionError as e:
            failures, worst, wabs = [f"{e}"], {}, {}
        if worst:
            ka, kr = max(wabs, key=wabs.get), max(worst, key=worst.get)
            print(f"{case['name']}: max |error| / largest entry {wabs[ka]:.1e} ({ka}); "
                  f"max relative error {worst[kr]:.1e} ({kr}, entries ≥ 1e-3 of the largest); "
                  f"Adam allowance above the floor for {cmp.loose} of {cmp.entries} weight entries")
        else:
            print(f"{case['name']}: not compared")
        for f in failures[:10]:
            print(f"  MISMATCH {f}")
        failed += bool(failures)
    if failed:
        print(f"{failed} of {len(cases)} cases disagree")
        sys.exit(1)
    print(f"{len(cases)} cases agree")


if __name__ == "__main__":
    main()
