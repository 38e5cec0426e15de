//! The learner's training round against an independent re-implementation in PyTorch
//! (`tests/crosscheck/round.py`, written from SPEC.md and sharing no code with the learner).
//!
//! For each configuration the learner runs two full rounds (G critic updates, then the actor and
//! temperature update) with its draws recorded ([`Selkd::draws`]). The initial state, the draws,
//! and the learner's state and reported losses after every update go to the Python script. It
//! builds its own networks from the same initial weights and, update by update, starts from the
//! learner's state before the update, performs the update on the same draws, and compares the
//! result: critics, target critics, actors, target actors, every Adam moment and step, log α,
//! and the reported losses. (Starting each update from the learner's state keeps float32
//! round-off from compounding through Adam, which divides by √v and so magnifies the round-off
//! of near-zero gradients; see the script's tolerances.) It also checks that training moved every
//! network that had a loss, so that the comparison cannot pass vacuously.
//!
//! `sac_updates_match_stable_baselines3` does the same for SAC against Stable-Baselines3's own
//! `SAC.train` (`tests/crosscheck/sb3_sac.py`), in the venv deploy/python.sh makes.
//!
//! Python with torch is found where `deploy/setup.sh` installs it (`SELKD_CACHE`, else
//! `XDG_CACHE_HOME/selkd`, else `~/.cache/selkd`, then `torch-2.11.0`). Every machine that runs
//! the tests has it (the build needs it), so a missing torch is a failure, not a skip.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use selkd_learner::config::{ActorQ, AlgoConfig, AlgoKeys, BackboneName, Sharing};
use selkd_learner::ensemble::Ensemble;
use selkd_learner::matmul::CpuGemm;
use selkd_learner::optim::Adam;
use selkd_learner::replay::{Batch, ReplayBuffer};
use selkd_learner::selkd::{Draw, RoundStats, Selkd};
use selkd_learner::targets::Formation;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::Command;
use tch::{Device, Kind, Tensor};

const OBS: usize = 4;
const ACT: usize = 2;

/// Small networks, but every size > 1 where it can be, and rates large enough that two rounds
/// move every weight and temperature well past float32 round-off.
fn base() -> AlgoKeys {
    AlgoKeys {
        actors: 3,
        critics: 5,
        subset: 2,
        utd: 2,
        batch_size: 16,
        hidden: vec![32, 32],
        lr: 1e-3,
        alpha_lr: 1e-2,
        ..AlgoKeys::default()
    }
}

/// (name, config, best actor in round 1 and round 2). The best changes between rounds so that the
/// distillation reference and "the best has no KD term" are exercised on two different actors.
/// Written as a config file's `[algo]` keys, read into the method as a config file is.
fn cases() -> Vec<(&'static str, AlgoConfig, [usize; 2])> {
    let b = base();
    let ensemble = |target| AlgoKeys {
        actors: 1,
        critics: 4,
        subset: 4,
        target,
        ..base()
    };
    vec![
        ("selkd (max-min, per-update)", b.clone(), [1, 2]),
        (
            "per-critic sharing",
            AlgoKeys {
                sharing: Sharing::PerCritic,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "min-min",
            AlgoKeys {
                target: Formation::MinMin,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "max-max",
            AlgoKeys {
                target: Formation::MaxMax,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "min-max",
            AlgoKeys {
                target: Formation::MinMax,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "average-dqn (max-mean)",
            ensemble(Formation::MaxMean),
            [0, 0],
        ),
        ("rem (max-rem)", ensemble(Formation::MaxRem), [0, 0]),
        (
            "aqe (max-aqe, drop 2 of 5)",
            AlgoKeys {
                critics: 5,
                subset: 5,
                aqe_drop: 2,
                ..ensemble(Formation::MaxAqe)
            },
            [0, 0],
        ),
        (
            "aqe with K = 3 (drop 1 of 3)",
            AlgoKeys {
                subset: 3,
                target: Formation::MaxAqe,
                aqe_drop: 1,
                ..b.clone()
            },
            [2, 0],
        ),
        (
            "dpd (paired critics)",
            AlgoKeys {
                actors: 2,
                critics: 4,
                paired_critics: true,
                ..b.clone()
            },
            [1, 0],
        ),
        (
            "td3 backbone",
            AlgoKeys {
                backbone: BackboneName::Td3,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "td3 backbone, per-critic, min-min",
            AlgoKeys {
                backbone: BackboneName::Td3,
                sharing: Sharing::PerCritic,
                target: Formation::MinMin,
                ..b.clone()
            },
            [2, 0],
        ),
        (
            "w/o rl",
            AlgoKeys {
                without_rl: true,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "w/o kd (kd_actors = [0])",
            AlgoKeys {
                kd_actors: Some(vec![0]),
                ..b.clone()
            },
            [2, 1],
        ),
        (
            "sac (K=1, N=M=2, actor min)",
            AlgoKeys {
                actors: 1,
                critics: 2,
                subset: 2,
                actor_q: ActorQ::Min,
                ..b.clone()
            },
            [0, 0],
        ),
        (
            "fixed α, λ_KD 0.5, actor min",
            AlgoKeys {
                fixed_alpha: Some(0.2),
                kd_weight: 0.5,
                actor_q: ActorQ::Min,
                ..b.clone()
            },
            [1, 2],
        ),
        (
            "actors updated G times per round (U = G, not Algorithm 1)",
            AlgoKeys {
                actor_updates_per_round: b.utd,
                ..b.clone()
            },
            [2, 0],
        ),
        (
            "target entropy −0.5",
            AlgoKeys {
                target_entropy: Some(-0.5),
                ..b.clone()
            },
            [0, 1],
        ),
    ]
    .into_iter()
    .map(|(name, keys, best)| (name, AlgoConfig::try_from(keys).expect(name), best))
    .collect()
}

fn tensor(t: &Tensor) -> Value {
    let t = t.detach().to_device(Device::Cpu).contiguous();
    let shape = t.size();
    let data: Vec<f64> = match t.kind() {
        Kind::Int64 => Vec::<i64>::try_from(t.reshape([-1]))
            .unwrap()
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        // f32 → f64 is exact, and JSON's f64 text reads back to the same f64.
        _ => Vec::<f32>::try_from(t.to_kind(Kind::Float).reshape([-1]))
            .unwrap()
            .into_iter()
            .map(f64::from)
            .collect(),
    };
    json!({ "shape": shape, "data": data })
}

fn ensemble(e: &Ensemble) -> Value {
    Value::Array(
        e.layers
            .iter()
            .map(|l| json!({ "weight": tensor(&l.weight), "bias": tensor(&l.bias) }))
            .collect(),
    )
}

fn adam(a: &Adam) -> Value {
    json!({
        "step": a.step,
        "exp_avg": a.exp_avg.iter().map(tensor).collect::<Vec<_>>(),
        "exp_avg_sq": a.exp_avg_sq.iter().map(tensor).collect::<Vec<_>>(),
    })
}

fn state(s: &Selkd) -> Value {
    json!({
        "actors": ensemble(&s.actors),
        "critics": ensemble(&s.critics),
        "target_critics": ensemble(&s.target_critics),
        "target_actors": s.target_actors.as_ref().map(ensemble),
        "log_alpha": tensor(&s.log_alpha),
        "actor_opt": adam(&s.actor_opt),
        "critic_opt": adam(&s.critic_opt),
        "alpha_opt": adam(&s.alpha_opt),
    })
}

fn batch(b: &Batch) -> Value {
    json!({
        "obs": tensor(&b.obs),
        "act": tensor(&b.act),
        "reward": tensor(&b.reward),
        "next_obs": tensor(&b.next_obs),
        "terminated": tensor(&b.terminated),
    })
}

fn draw(d: &Draw) -> Value {
    match d {
        Draw::CriticBatch(b, subsets) => {
            json!({ "kind": "critic_batch", "batch": batch(b), "subsets": subsets })
        }
        Draw::ActorBatch(b) => json!({ "kind": "actor_batch", "batch": batch(b) }),
        Draw::Normal(t) => json!({ "kind": "normal", "value": tensor(t) }),
        Draw::Uniform(t) => json!({ "kind": "uniform", "value": tensor(t) }),
    }
}

fn stats(s: &RoundStats) -> Value {
    json!({
        "critic_loss": s.critic_loss,
        "q_mean": s.q_mean,
        "actor_loss": s.actor_loss,
        "alpha": s.alpha,
        "kl_to_best": s.kl_to_best,
        "entropy": s.entropy,
    })
}

fn replay(seed: u64) -> ReplayBuffer {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut rb = ReplayBuffer::new(1000, OBS, ACT, Device::Cpu);
    for i in 0..300 {
        let mut v = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
        let (s, a, s2) = (v(OBS), v(ACT), v(OBS));
        rb.push(&s, &a, rng.gen_range(-2.0..2.0), &s2, i % 5 == 0);
    }
    rb
}

/// Two rounds, driven one update at a time so that every update's result is recorded: per round,
/// G critic updates, each of the last U (`actor_updates_per_round`, 1 in Algorithm 1) followed by
/// an actor update, which is what `train_round` does (checked: a twin trained by `train_round`
/// ends bit-identical, with the same statistics).
fn run_case(name: &str, cfg: &AlgoConfig, best: [usize; 2], seed: u64) -> Value {
    let mut s = Selkd::new(cfg, OBS, ACT, Device::Cpu, seed);
    let mut rb = replay(seed + 100);
    let initial = state(&s);
    let mut updates = Vec::new();
    let mut round_stats = Vec::new();
    for &b in &best {
        let mut st = RoundStats::default();
        for g in 1..=cfg.utd {
            s.draws = Some(Vec::new());
            let (loss, q) = s.update_critics(&mut rb);
            st.critic_loss += loss / cfg.utd as f64;
            st.q_mean += q / cfg.utd as f64;
            let draws: Vec<Value> = s.draws.take().unwrap().iter().map(draw).collect();
            updates.push(json!({
                "kind": "critic", "draws": draws, "loss": loss, "q_mean": q, "state": state(&s),
            }));
            if g > cfg.utd - cfg.actor_updates_per_round {
                s.draws = Some(Vec::new());
                s.update_actors(&mut rb, b, &mut st);
                let draws: Vec<Value> = s.draws.take().unwrap().iter().map(draw).collect();
                updates.push(json!({
                    "kind": "actor", "best": b, "draws": draws, "stats": stats(&st), "state": state(&s),
                }));
            }
        }
        round_stats.push(stats(&st));
    }
    let mut twin = Selkd::new(cfg, OBS, ACT, Device::Cpu, seed);
    let mut rb2 = replay(seed + 100);
    for (r, &b) in best.iter().enumerate() {
        let st = twin.train_round(&mut rb2, b);
        assert_eq!(
            stats(&st),
            round_stats[r],
            "{name}: train_round's statistics, round {r}"
        );
    }
    assert!(
        state(&twin) == state(&s),
        "{name}: train_round is G critic updates, then the actor update"
    );
    json!({
        "name": name,
        "cfg": serde_json::to_value(cfg).unwrap(),
        "obs_dim": OBS,
        "act_dim": ACT,
        "initial": initial,
        "updates": updates,
    })
}

/// Where `deploy/setup.sh` puts torch: the same rule, so the test finds what the build used.
fn torch_dir() -> PathBuf {
    let cache = std::env::var_os("SELKD_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            let xdg = std::env::var_os("XDG_CACHE_HOME")
                .map(PathBuf::from)
                .unwrap_or_else(|| {
                    PathBuf::from(std::env::var_os("HOME").expect("HOME is set")).join(".cache")
                });
            xdg.join("selkd")
        });
    cache.join("torch-2.11.0")
}

/// `interpreter` on one thread, writing no bytecode into the source tree.
fn python_at(interpreter: &std::path::Path) -> Command {
    let mut c = Command::new(interpreter);
    c.env("OMP_NUM_THREADS", "1")
        .env("PYTHONDONTWRITEBYTECODE", "1");
    c
}

/// The system's python3 with the torch `deploy/setup.sh` installed.
fn python() -> Command {
    let mut c = python_at("python3".as_ref());
    c.env("PYTHONPATH", torch_dir());
    c
}

/// Runs `python tests/crosscheck/SCRIPT INPUT.json` on `input`, written to a temporary file;
/// prints what the script said; returns whether it succeeded and its stdout.
fn run_script(mut python: Command, script: &str, input: &impl serde::Serialize) -> (bool, String) {
    let work = std::env::temp_dir().join(format!("selkd-{script}-{}", std::process::id()));
    std::fs::create_dir_all(&work).unwrap();
    let file = work.join("input.json");
    std::fs::write(&file, serde_json::to_vec(input).unwrap()).unwrap();
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/crosscheck")
        .join(script);
    let out = python.arg(&path).arg(&file).output().unwrap();
    let _ = std::fs::remove_dir_all(&work);
    let report = String::from_utf8_lossy(&out.stdout).into_owned();
    eprintln!("{report}{}", String::from_utf8_lossy(&out.stderr));
    (out.status.success(), report)
}

#[test]
fn two_rounds_match_an_independent_pytorch_implementation() {
    let dir = torch_dir();
    let probe = python()
        .args(["-c", "import torch; print(torch.__version__)"])
        .output();
    match probe {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!(
            "python3 cannot import torch from {} (run deploy/setup.sh): {}",
            dir.display(),
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => panic!(
            "python3 is needed for this test (it runs torch from {}): {e}",
            dir.display()
        ),
    }
    // SELKD_CROSSCHECK_SEEDS=S runs every case on S sets of seeds (draws and weights) instead of
    // one, to soak the comparison's tolerances.
    let seeds: u64 = std::env::var("SELKD_CROSSCHECK_SEEDS")
        .map(|v| v.parse().expect("SELKD_CROSSCHECK_SEEDS is a count"))
        .unwrap_or(1);
    let started = std::time::Instant::now();
    let mut cases_json = Vec::new();
    for round in 0..seeds {
        for (i, (name, cfg, best)) in cases().iter().enumerate() {
            let name = if seeds > 1 {
                format!("{name} (seed set {round})")
            } else {
                name.to_string()
            };
            cases_json.push(run_case(&name, cfg, *best, 10 + i as u64 + 1000 * round));
        }
    }
    // The cases above multiply the critics' fp32 matrices as `run.cpu_gemm = "auto"` chooses on
    // this CPU; the first case again with the other choice, so that both are checked anywhere.
    let other = match CpuGemm::Auto.resolved() {
        CpuGemm::Gemm => CpuGemm::Libtorch,
        _ => CpuGemm::Gemm,
    };
    selkd_learner::matmul::set(other);
    assert_eq!(selkd_learner::matmul::chosen(), other);
    let (name, cfg, best) = &cases()[0];
    let name = format!("{name}, fp32 products by {}", other.describe());
    cases_json.push(run_case(&name, cfg, *best, 10));
    selkd_learner::matmul::set(CpuGemm::Auto);
    let cases = cases_json;
    let learner_s = started.elapsed().as_secs_f64();
    let (ok, report) = run_script(python(), "round.py", &cases);
    eprintln!(
        "learner {learner_s:.1} s, JSON and PyTorch {:.1} s",
        started.elapsed().as_secs_f64() - learner_s
    );
    assert!(
        ok,
        "the PyTorch re-implementation disagrees with the learner (report above)"
    );
    assert!(
        report.contains(&format!("{} cases agree", cases.len())),
        "the script did not check every case"
    );
}

/// The project's Python venv (deploy/python.sh: `SELKD_PYTHON_VENV`, else `python-venv` beside
/// torch in the cache), which holds Stable-Baselines3.
fn venv_python() -> PathBuf {
    std::env::var_os("SELKD_PYTHON_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| torch_dir().with_file_name("python-venv"))
        .join("bin/python")
}

/// Our SAC (K = 1, N = M = 2, the actor on min(Q1, Q2)) against Stable-Baselines3's own
/// `SAC.train`, not a re-implementation: update by update, SB3 starts from the learner's state and
/// steps on the learner's mini-batch and noise (`tests/crosscheck/sb3_sac.py` says how, and what
/// each update compares). SB3 has one learning rate, so α's is the networks' here.
#[test]
fn sac_updates_match_stable_baselines3() {
    let python = venv_python();
    assert!(
        python.exists(),
        "{} is missing: run deploy/python.sh (it installs stable-baselines3 there)",
        python.display()
    );
    let cfg = AlgoConfig::try_from(AlgoKeys {
        actors: 1,
        critics: 2,
        subset: 2,
        actor_q: ActorQ::Min,
        alpha_lr: base().lr,
        ..base()
    })
    .unwrap();
    let case = run_case("sac against sb3", &cfg, [0, 0], 21);
    let (ok, report) = run_script(python_at(&python), "sb3_sac.py", &case);
    assert!(
        ok,
        "Stable-Baselines3's SAC disagrees with the learner (report above)"
    );
    assert!(
        report.contains("updates agree with Stable-Baselines3"),
        "the script did not compare the updates"
    );
}
