//! The messages between the SELKD learner and its actor workers, and the names of the iceoryx2
//! services that carry them. Types here carry no training logic.
//!
//! | service                    | direction        | payload                                   |
//! |----------------------------|------------------|-------------------------------------------|
//! | `selkd/<run>/transitions`  | worker → learner | [`TransitionHeader`] + `[f32]` row        |
//! | `selkd/<run>/reports`      | worker → learner | [`Report`] (hello, evaluation)            |
//! | `selkd/<run>/weights/<i>`  | learner → worker | [`WeightsHeader`] + `[f32]` actor weights |
//! | `selkd/<run>/cursor/<i>`   | learner → worker | [`CursorHeader`] + `[f32]` episode's actions |
//! | `selkd/<run>/control`      | learner → all    | [`Control`] (run facts, budgets, stop)    |
//! | `selkd/<run>/ranking`      | learner → all    | [`Ranking`]                               |
//! | `selkd/<run>/to-learner`   | event            | "something for the learner"               |
//! | `selkd/<run>/to-workers`   | event            | "something for the workers"               |
//!
//! [`WorkerPorts`] and [`LearnerPorts`] open each side's ports of these services; [`check_peer`]
//! is the handshake both sides run on [`Handshake`] (the learner's in [`Control`], a worker's in
//! its hello [`Report`]).
//!
//! Weights, control and ranking keep a history of one, so a worker that starts late (or restarts)
//! gets the current ones at once. Transitions are never dropped: the learner's buffer is sized
//! above what the budgets in [`Control`] let workers have in flight, and overflow is off.
//!
//! The learner is the record of where each worker's rollout stands. A worker that starts (the
//! first time, restarted after a crash, or in a run resumed from a checkpoint) says hello and
//! waits for its cursor: how many transitions the learner has from it, and the episode and step
//! they reach, with the actions of that episode so far. Its episodes are seeded by their index and
//! its actions by (episode, step), so replaying those actions on the episode's seed puts it exactly
//! where the learner's record ends: nothing is sent twice, nothing is skipped.

pub mod lock;
mod ports;
pub mod stale;

pub use ports::{LearnerPorts, WorkerPorts};

use iceoryx2::prelude::*;

/// Bumped whenever a message layout or meaning changes; checked in the handshake.
pub const PROTOCOL_VERSION: u32 = 5;
/// Most actors a run may have (fixed arrays in [`Control`] and [`Ranking`]).
pub const MAX_ACTORS: usize = 64;
pub const MAX_HIDDEN_LAYERS: usize = 8;
/// Transitions the learner's subscriber holds before a publisher would have to wait.
pub const TRANSITION_BUFFER: usize = 16_384;

/// A short fixed-size name (env id), zero-padded UTF-8.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::Name")]
pub struct Name(pub [u8; NAME_BYTES]);

impl Default for Name {
    fn default() -> Self {
        Name([0; NAME_BYTES])
    }
}

/// The longest name a message carries: room for `gymnasium:` ids of third-party packages
/// (`gymnasium:InvertedDoublePendulum-v5` is already 35 bytes). Configs are checked against it.
pub const NAME_BYTES: usize = 96;

impl Name {
    pub fn new(s: &str) -> Self {
        let mut b = [0u8; NAME_BYTES];
        let n = s.len().min(NAME_BYTES);
        b[..n].copy_from_slice(&s.as_bytes()[..n]);
        Name(b)
    }
    pub fn as_str(&self) -> &str {
        let end = self.0.iter().position(|&c| c == 0).unwrap_or(NAME_BYTES);
        std::str::from_utf8(&self.0[..end]).unwrap_or("<invalid>")
    }
}

/// One transition `(s, a, r, s', terminated, truncated)`. The `[f32]` payload is the row
/// `s (obs) | a (act) | r | s' (obs) | terminated | truncated`, see [`TransitionRow`].
#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::TransitionHeader")]
pub struct TransitionHeader {
    pub worker: u32,
    /// How many times this worker was (re)started before this process.
    pub generation: u32,
    /// This process's [`Report::incarnation`]: the learner stores transitions only from the
    /// process it handed the worker's cursor to.
    pub incarnation: u64,
    pub episode: u64,
    /// Index of this step within its episode.
    pub step: u64,
    /// Weights version of the behaviour policy that chose `a` (0 = warm-up random action).
    pub policy_version: u64,
    pub obs_dim: u32,
    pub act_dim: u32,
    /// The episode's undiscounted return when this transition ends it, else NaN.
    pub episode_return: f64,
}

/// Offsets into a transition row.
///
/// A worker writes a row, the learner splits it back into its fields:
///
/// ```no_run
/// use selkd_protocol::TransitionRow;
///
/// let row = TransitionRow { obs_dim: 3, act_dim: 1 }; // Pendulum's sizes
/// let mut buf = Vec::with_capacity(row.len());
/// let (s, a, s2) = ([1.0, 0.0, 0.5], [0.25], [0.99, 0.1, 0.4]);
/// row.write(&mut buf, &s, &a, -0.3, &s2, false, true);
/// assert_eq!(buf.len(), row.len()); // 2·obs + act + 3
///
/// let (s_, a_, r, s2_, terminated, truncated) = row.split(&buf);
/// assert_eq!((s_, a_, r, s2_), (&s[..], &a[..], -0.3, &s2[..]));
/// // A time limit (truncated) is not a terminal state: the learner still bootstraps from s'.
/// assert!(!terminated && truncated);
/// assert_eq!(row.field_of(4), "r");
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TransitionRow {
    pub obs_dim: usize,
    pub act_dim: usize,
}

impl TransitionRow {
    pub fn len(&self) -> usize {
        2 * self.obs_dim + self.act_dim + 3
    }
    pub fn is_empty(&self) -> bool {
        false
    }
    // One argument per field of a transition: a struct would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn write(
        &self,
        out: &mut Vec<f32>,
        s: &[f32],
        a: &[f32],
        r: f32,
        s2: &[f32],
        terminated: bool,
        truncated: bool,
    ) {
        out.clear();
        out.extend_from_slice(s);
        out.extend_from_slice(a);
        out.push(r);
        out.extend_from_slice(s2);
        out.push(terminated as u8 as f32);
        out.push(truncated as u8 as f32);
    }
    /// Which part of a row index `i` falls in: `s[j]`, `a[j]`, `r`, `s'[j]` or a flag.
    pub fn field_of(&self, i: usize) -> String {
        let (o, a) = (self.obs_dim, self.act_dim);
        match i {
            i if i < o => format!("s[{i}]"),
            i if i < o + a => format!("a[{}]", i - o),
            i if i == o + a => "r".to_string(),
            i if i < 2 * o + a + 1 => format!("s'[{}]", i - o - a - 1),
            _ => "flags".to_string(),
        }
    }
    /// `(s, a, r, s', terminated, truncated)` views into a row of the right length.
    pub fn split<'a>(&self, row: &'a [f32]) -> (&'a [f32], &'a [f32], f32, &'a [f32], bool, bool) {
        let (o, a) = (self.obs_dim, self.act_dim);
        (
            &row[..o],
            &row[o..o + a],
            row[o + a],
            &row[o + a + 1..2 * o + a + 1],
            row[2 * o + a + 1] != 0.0,
            row[2 * o + a + 2] != 0.0,
        )
    }
}

/// Header of an actor's weights (flat `f32`, `selkd_policy` layout).
#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::WeightsHeader")]
pub struct WeightsHeader {
    pub actor: u32,
    pub version: u64,
}

/// Where a worker's rollout continues (see the crate doc); the payload is the actions of episode
/// `episode` so far, `step × act_dim` values.
#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::CursorHeader")]
pub struct CursorHeader {
    pub worker: u32,
    /// The worker process this cursor is for (its hello's incarnation).
    pub incarnation: u64,
    /// Transitions the learner has from this worker: the next one sent is number `sent`.
    pub sent: u64,
    /// The episode (counted per worker from 0) the next transition belongs to.
    pub episode: u64,
    /// Its step within that episode.
    pub step: u64,
}

/// What a worker reports besides transitions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::ReportKind")]
pub enum ReportKind {
    /// A worker (re)joined: the handshake's worker side.
    Hello = 0,
    /// The evaluation episodes of one epoch are done.
    Evaluation = 1,
}

#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::Report")]
pub struct Report {
    pub kind: ReportKind,
    pub worker: u32,
    pub generation: u32,
    /// Random, fixed for the life of one worker process: tells a restarted (or duplicate)
    /// process from the one it replaces.
    pub incarnation: u64,
    pub protocol_version: u32,
    pub env: Name,
    /// Fingerprint of the env's options and physics (`selkd_envs::variant_fingerprint`).
    pub env_options: u64,
    pub obs_dim: u32,
    pub act_dim: u32,
    /// Weights version the worker holds (hello) or evaluated (evaluation).
    pub weights_version: u64,
    /// Evaluation epoch (1-based), 0 for hello.
    pub epoch: u64,
    pub episodes: u32,
    /// Mean undiscounted return of the evaluation episodes.
    pub mean_return: f64,
    /// Fraction of successful episodes, or NaN where the task has no success.
    pub success_rate: f64,
}

/// The learner's standing orders, one for all workers (history 1: latecomers read it at once).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::Control")]
pub struct Control {
    pub protocol_version: u32,
    pub actors: u32,
    pub env: Name,
    /// Fingerprint of the env's options and physics (`selkd_envs::variant_fingerprint`).
    pub env_options: u64,
    pub obs_dim: u32,
    pub act_dim: u32,
    pub seed: u64,
    /// Hidden layer sizes of the actor network (first `hidden_layers` entries).
    pub hidden: [u32; MAX_HIDDEN_LAYERS],
    pub hidden_layers: u32,
    /// Per actor: uniform-random warm-up steps before the policy acts.
    pub warmup_steps: u64,
    /// Most recent weights version published for every actor.
    pub weights_version: u64,
    /// A worker must not act with weights older than `weights_version − max_policy_lag`.
    pub max_policy_lag: u64,
    /// Evaluate once for every epoch up to this one (0 = none yet).
    pub eval_epoch: u64,
    pub eval_episodes: u32,
    /// 0: act by sampling the stochastic policy (SAC). Above 0: act deterministically, `tanh(μ)`,
    /// plus Gaussian noise of this std, clipped to [-1, 1] (TD3).
    pub exploration_noise: f32,
    pub stop: u32,
    /// Per actor: a worker may send transitions while its count is below this.
    pub budget: [u64; MAX_ACTORS],
}

/// Every actor's Monte-Carlo score and the best one (ties to the lower index).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("selkd::Ranking")]
pub struct Ranking {
    pub version: u64,
    pub actors: u32,
    pub best: u32,
    /// NaN where an actor has no score yet.
    pub scores: [f64; MAX_ACTORS],
}

/// Service names of one run. The run id keeps two runs on one host apart.
#[derive(Debug, Clone)]
pub struct Services {
    pub run_id: String,
}

impl Services {
    pub fn new(run_id: &str) -> Self {
        Self {
            run_id: run_id.to_string(),
        }
    }
    fn name(&self, what: &str) -> Result<ServiceName, ProtocolError> {
        let s = format!("selkd/{}/{}", self.run_id, what);
        ServiceName::new(&s).map_err(|e| ProtocolError::Name(s, format!("{e:?}")))
    }
    pub fn transitions(&self) -> Result<ServiceName, ProtocolError> {
        self.name("transitions")
    }
    pub fn reports(&self) -> Result<ServiceName, ProtocolError> {
        self.name("reports")
    }
    pub fn weights(&self, actor: usize) -> Result<ServiceName, ProtocolError> {
        self.name(&format!("weights/{actor}"))
    }
    pub fn cursor(&self, actor: usize) -> Result<ServiceName, ProtocolError> {
        self.name(&format!("cursor/{actor}"))
    }
    pub fn control(&self) -> Result<ServiceName, ProtocolError> {
        self.name("control")
    }
    pub fn ranking(&self) -> Result<ServiceName, ProtocolError> {
        self.name("ranking")
    }
    pub fn to_learner(&self) -> Result<ServiceName, ProtocolError> {
        self.name("to-learner")
    }
    pub fn to_workers(&self) -> Result<ServiceName, ProtocolError> {
        self.name("to-workers")
    }
}

/// Room for restarted workers overlapping their dead predecessors until cleanup (ports, and
/// nodes: iceoryx2 allows 20 nodes per service unless told more, too few for K ≥ 20).
pub fn max_ports(actors: usize) -> usize {
    2 * actors + 4
}

/// What each side shows in the handshake: the facts of a run a worker must share with its
/// learner. The learner's are in its [`Control`], a worker's in its hello [`Report`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Handshake {
    pub protocol_version: u32,
    pub env: Name,
    /// Fingerprint of the env's options and physics (`selkd_envs::variant_fingerprint`).
    pub env_options: u64,
    pub obs_dim: u32,
    pub act_dim: u32,
}

impl Handshake {
    /// This build's side, for an env of these sizes and options.
    pub fn ours(env: &str, env_options: u64, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            protocol_version: PROTOCOL_VERSION,
            env: Name::new(env),
            env_options,
            obs_dim: obs_dim as u32,
            act_dim: act_dim as u32,
        }
    }
}

impl std::fmt::Display for Handshake {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "protocol v{}, env `{}`, obs {}, act {}",
            self.protocol_version,
            self.env.as_str(),
            self.obs_dim,
            self.act_dim
        )
    }
}

/// This build's orders with nothing set: no actors, no env, nothing granted. Tests and tools
/// set the fields they need on it (`Control { actors: 2, ..Default::default() }`).
impl Default for Control {
    fn default() -> Self {
        Self {
            protocol_version: PROTOCOL_VERSION,
            actors: 0,
            env: Name::default(),
            env_options: 0,
            obs_dim: 0,
            act_dim: 0,
            seed: 0,
            hidden: [0; MAX_HIDDEN_LAYERS],
            hidden_layers: 0,
            warmup_steps: 0,
            weights_version: 0,
            max_policy_lag: 0,
            eval_epoch: 0,
            eval_episodes: 0,
            exploration_noise: 0.0,
            stop: 0,
            budget: [0; MAX_ACTORS],
        }
    }
}

impl Control {
    pub fn handshake(&self) -> Handshake {
        Handshake {
            protocol_version: self.protocol_version,
            env: self.env,
            env_options: self.env_options,
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
        }
    }
}

impl Report {
    /// Worker `worker`'s hello (process `incarnation`, of its `generation`) showing handshake
    /// `h`; an evaluation report is the same with its fields set.
    pub fn hello(h: Handshake, worker: u32, generation: u32, incarnation: u64) -> Self {
        Self {
            kind: ReportKind::Hello,
            worker,
            generation,
            incarnation,
            protocol_version: h.protocol_version,
            env: h.env,
            env_options: h.env_options,
            obs_dim: h.obs_dim,
            act_dim: h.act_dim,
            weights_version: 0,
            epoch: 0,
            episodes: 0,
            mean_return: f64::NAN,
            success_rate: f64::NAN,
        }
    }

    pub fn handshake(&self) -> Handshake {
        Handshake {
            protocol_version: self.protocol_version,
            env: self.env,
            env_options: self.env_options,
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ProtocolError {
    #[error("invalid service name `{0}`: {1}; run ids may use letters, digits, '-' and '_'")]
    Name(String, String),
    #[error(
        "this worker does not fit the run: learner has {learner}; worker has {worker}. \
         Start the worker with the run's env and the same selkd build"
    )]
    // Boxed: a Handshake holds a 96-byte name, and every service name's Result carries this type.
    Mismatch {
        learner: Box<Handshake>,
        worker: Box<Handshake>,
    },
    #[error(
        "this worker runs env `{}` with other options or physics settings than the run \
         (fingerprint {:x}, the run's {:x}): start it with the run's [env_options] as \
         --env-options and from the same selkd build (`selkd train` does both)",
        worker.env.as_str(), worker.env_options, learner.env_options
    )]
    OptionsMismatch {
        learner: Box<Handshake>,
        worker: Box<Handshake>,
    },
}

/// The handshake, on either side (a worker checks the learner's [`Control`], the learner each
/// hello [`Report`]): does the worker fit the run? The error names both sides' values.
pub fn check_peer(learner: &Handshake, worker: &Handshake) -> Result<(), ProtocolError> {
    let apart_from_options = |h: &Handshake| Handshake {
        env_options: 0,
        ..*h
    };
    let (learner, worker) = (Box::new(*learner), Box::new(*worker));
    match (
        apart_from_options(&learner) == apart_from_options(&worker),
        learner.env_options == worker.env_options,
    ) {
        (true, true) => Ok(()),
        (true, false) => Err(ProtocolError::OptionsMismatch { learner, worker }),
        (false, _) => Err(ProtocolError::Mismatch { learner, worker }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn control() -> Control {
        Control {
            actors: 2,
            env: Name::new("pendulum"),
            env_options: 7,
            obs_dim: 3,
            act_dim: 1,
            max_policy_lag: 1,
            eval_episodes: 1,
            ..Default::default()
        }
    }

    #[test]
    fn handshake_accepts_a_match_and_names_both_sides_of_a_mismatch() {
        let learner = control().handshake();
        let check = |env, options, obs, act| {
            check_peer(&learner, &Handshake::ours(env, options, obs, act))
                .map_err(|e| e.to_string())
        };
        assert!(check("pendulum", 7, 3, 1).is_ok());
        let e = check("pendulum", 8, 3, 1).unwrap_err();
        assert!(
            e.contains("other options")
                && e.contains("--env-options")
                && e.contains("fingerprint 8, the run's 7"),
            "{e}"
        );
        let e = check("hopper", 7, 11, 3).unwrap_err();
        assert!(
            e.contains("learner has protocol v5, env `pendulum`, obs 3, act 1")
                && e.contains("worker has protocol v5, env `hopper`, obs 11, act 3"),
            "{e}"
        );
        // A worker of another env is a mismatch of env, even with other options as well.
        let e = check("hopper", 8, 11, 3).unwrap_err();
        assert!(e.contains("does not fit"), "{e}");
        // The learner's side of the same check: a hello from a worker of another build.
        let hello = Report {
            protocol_version: PROTOCOL_VERSION - 1,
            ..report(Handshake::ours("pendulum", 7, 3, 1))
        };
        let e = check_peer(&learner, &hello.handshake())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("learner has protocol v5") && e.contains("worker has protocol v4"),
            "{e}"
        );
    }

    fn report(h: Handshake) -> Report {
        Report::hello(h, 0, 0, 1)
    }

    #[test]
    fn rows_round_trip() {
        let row = TransitionRow {
            obs_dim: 2,
            act_dim: 1,
        };
        let mut v = Vec::new();
        row.write(&mut v, &[1.0, 2.0], &[0.5], -3.0, &[4.0, 5.0], true, false);
        assert_eq!(v.len(), row.len());
        assert_eq!(
            row.split(&v),
            (
                &[1.0, 2.0][..],
                &[0.5][..],
                -3.0,
                &[4.0, 5.0][..],
                true,
                false
            )
        );
        assert_eq!(Name::new("pendulum").as_str(), "pendulum");
        // Sizes where 2 × obs and 2 + obs differ, and every index named.
        let row = TransitionRow {
            obs_dim: 3,
            act_dim: 2,
        };
        assert_eq!(row.len(), 11, "s 3, a 2, r, s' 3, two flags");
        assert!(!row.is_empty());
        let v: Vec<f32> = (0..11).map(|i| i as f32).collect();
        let (s, a, r, s2, terminated, truncated) = row.split(&v);
        assert_eq!((s, a, r, s2), (&v[0..3], &v[3..5], 5.0, &v[6..9]));
        assert!(terminated && truncated, "9 and 10 are not 0");
        // Each flag read from its own index: every other value is non-zero, so a flag read one
        // place off (from s' or the other flag) comes out wrong in one of the four cases.
        let mut v = Vec::new();
        for (term, trunc) in [(false, false), (true, false), (false, true), (true, true)] {
            let (s, a, s2) = ([1.0, 2.0, 3.0], [4.0, 5.0], [7.0, 8.0, 9.0]);
            row.write(&mut v, &s, &a, 6.0, &s2, term, trunc);
            assert_eq!(
                row.split(&v),
                (&s[..], &a[..], 6.0, &s2[..], term, trunc),
                "terminated {term}, truncated {trunc}"
            );
        }
        let names: Vec<String> = (0..11).map(|i| row.field_of(i)).collect();
        assert_eq!(
            names,
            [
                "s[0]", "s[1]", "s[2]", "a[0]", "a[1]", "r", "s'[0]", "s'[1]", "s'[2]", "flags",
                "flags"
            ]
        );
    }

    /// A run id of its own per test: tests run in parallel, and iceoryx2's services are
    /// host-wide.
    fn run_id(test: &str) -> String {
        format!("t{}-{test}", std::process::id())
    }

    #[test]
    fn each_run_and_each_service_has_its_own_name() {
        let (a, b) = (Services::new("run-a"), Services::new("run-b"));
        let names = |s: &Services| -> Vec<String> {
            let mut v = vec![
                s.transitions(),
                s.reports(),
                s.control(),
                s.ranking(),
                s.to_learner(),
                s.to_workers(),
            ];
            for i in 0..3 {
                v.push(s.weights(i));
                v.push(s.cursor(i));
            }
            v.into_iter()
                .map(|n| n.unwrap().as_str().to_string())
                .collect()
        };
        let (na, nb) = (names(&a), names(&b));
        assert_eq!(na[0], "selkd/run-a/transitions");
        assert_eq!(na[6], "selkd/run-a/weights/0");
        assert_eq!(na[9], "selkd/run-a/cursor/1");
        let mut all: Vec<&String> = na.iter().chain(&nb).collect();
        let n = all.len();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), n, "no two services share a name: {na:?} {nb:?}");
        assert!(na.iter().all(|n| n.starts_with("selkd/run-a/")));
        // iceoryx2 takes names of at most 255 bytes.
        let e = Services::new(&"r".repeat(300)).transitions().unwrap_err();
        assert!(e.to_string().contains("run ids may use"), "{e}");
    }

    #[test]
    fn node_names_carry_the_run_and_the_worker_and_fit_iceoryx2() {
        assert_eq!(learner_node_name("r1"), "learner-r1");
        assert_eq!(worker_node_name("r1", 3), "actor-worker-3-r1");
        assert_ne!(worker_node_name("r1", 1), worker_node_name("r1", 2));
        // A long run id: cut to iceoryx2's 128 bytes, which it takes.
        let name = worker_node_name(&"r".repeat(200), 1);
        assert_eq!(name.len(), 128);
        assert!(name.starts_with("actor-worker-1-rrr"));
        let n = services::node(&name);
        assert!(n.is_ok(), "iceoryx2 takes the cut name: {:?}", n.err());
        // Of 2-byte characters: cut at a character boundary (15 ASCII bytes, then 56 whole
        // characters), never inside one.
        let name = worker_node_name(&"é".repeat(100), 1);
        assert_eq!(name.len(), 127);
        assert!(name.starts_with("actor-worker-1-é") && name.ends_with('é'));
    }

    /// A restarted worker's ports overlap its dead predecessor's until iceoryx2 cleans them up,
    /// so a run of K actors must take 2K workers' ports (and nodes) beside the learner's.
    #[test]
    fn a_run_has_room_for_every_worker_and_a_dead_predecessor_of_each() {
        let actors = 8;
        let svc = Services::new(&run_id("room"));
        let learner = services::node(&learner_node_name(&svc.run_id)).unwrap();
        let ports = ports::LearnerPorts::open(&learner, &svc, actors, 4).unwrap();
        let row = TransitionRow {
            obs_dim: 3,
            act_dim: 1,
        };
        let mut workers = vec![];
        for w in 0..2 * actors {
            let node = services::node(&format!(
                "{}-{w}",
                worker_node_name(&svc.run_id, w % actors)
            ))
            .unwrap();
            let control = ports::WorkerPorts::control(&node, &svc).unwrap();
            let opened =
                ports::WorkerPorts::open(&node, &svc, control, w % actors, actors, row.len());
            assert!(
                opened.is_ok(),
                "worker {w} of {}: {:?}",
                2 * actors,
                opened.err()
            );
            workers.push((node, opened));
        }
        drop(ports);
    }

    /// Every service's sizes, worked out by hand for K = 8: they are part of the protocol
    /// (iceoryx2 refuses to open a service with larger limits than the ones it was created
    /// with), so a change must come with a new `PROTOCOL_VERSION`. Per-run services: 2 ports
    /// per actor (a worker and its dead predecessor until cleanup) and 4 to spare, 20 at K = 8;
    /// the wake-up to the learner 2 more (22), with the learner and a successor as listeners.
    /// Services every worker of any run shape may read: 2 × 64 + 4 = 132 nodes and readers.
    #[test]
    fn every_service_is_sized_as_the_protocol_says() {
        let svc = Services::new(&run_id("sizes"));
        let node = services::node(&learner_node_name(&svc.run_id)).unwrap();
        let transitions = services::transitions(&node, &svc, 8).unwrap();
        let reports = services::reports(&node, &svc, 8).unwrap();
        let weights = services::weights(&node, &svc, 0).unwrap();
        let cursor = services::cursor(&node, &svc, 0).unwrap();
        let control = services::control(&node, &svc).unwrap();
        let ranking = services::ranking(&node, &svc).unwrap();
        // (nodes, publishers, subscribers) and (a subscriber's buffer, history).
        for (name, c, ports, buffers) in [
            (
                "transitions",
                transitions.static_config(),
                (20, 20, 2),
                (16_384, 0),
            ),
            ("reports", reports.static_config(), (20, 20, 2), (256, 0)),
            ("weights", weights.static_config(), (132, 2, 132), (1, 1)),
            ("cursor", cursor.static_config(), (132, 2, 132), (1, 1)),
            ("control", control.static_config(), (132, 2, 132), (1, 1)),
            ("ranking", ranking.static_config(), (132, 2, 132), (1, 1)),
        ] {
            assert_eq!(
                (c.max_nodes(), c.max_publishers(), c.max_subscribers()),
                ports,
                "{name}"
            );
            assert_eq!(
                (c.subscriber_max_buffer_size(), c.history_size()),
                buffers,
                "{name}"
            );
        }
        let e = services::to_learner(&node, &svc, 8).unwrap();
        let c = e.static_config();
        assert_eq!(
            (c.max_nodes(), c.max_notifiers(), c.max_listeners()),
            (22, 22, 2),
            "to-learner"
        );
        let e = services::to_workers(&node, &svc).unwrap();
        let c = e.static_config();
        assert_eq!(
            (c.max_nodes(), c.max_notifiers(), c.max_listeners()),
            (132, 2, 132),
            "to-workers"
        );
    }

    /// The learner waking every worker: room for twice the most actors a run may have.
    #[test]
    fn the_wake_up_call_reaches_twice_the_most_actors() {
        let svc = Services::new(&run_id("wake"));
        let learner = services::node(&learner_node_name(&svc.run_id)).unwrap();
        let _notifier = services::to_workers(&learner, &svc)
            .unwrap()
            .notifier_builder()
            .create()
            .unwrap();
        let listeners: Vec<_> = (0..2 * MAX_ACTORS)
            .map(|w| {
                let node = services::node(&format!("w{w}-{}", svc.run_id)).unwrap();
                let l = services::to_workers(&node, &svc)
                    .unwrap_or_else(|e| panic!("worker {w}: {e}"))
                    .listener_builder()
                    .create()
                    .unwrap_or_else(|e| panic!("worker {w}: {e}"));
                (node, l)
            })
            .collect();
        assert_eq!(listeners.len(), 2 * MAX_ACTORS);
    }

    /// While the learner is busy (a long update), every worker may report a few times: the
    /// reports service keeps four per actor at the most actors, none dropped.
    #[test]
    fn reports_wait_for_a_busy_learner_four_per_actor() {
        use iceoryx2::prelude::BackpressureStrategy;
        let svc = Services::new(&run_id("reports"));
        let learner = services::node(&learner_node_name(&svc.run_id)).unwrap();
        let subscriber = services::reports(&learner, &svc, 2)
            .unwrap()
            .subscriber_builder()
            .create()
            .unwrap();
        let worker = services::node(&worker_node_name(&svc.run_id, 0)).unwrap();
        // Discard instead of the default wait, so that too small a buffer fails, not hangs.
        let publisher = services::reports(&worker, &svc, 2)
            .unwrap()
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .unwrap();
        let n = 4 * MAX_ACTORS;
        for e in 0..n {
            let r = Report {
                epoch: e as u64,
                ..report(Handshake::ours("pendulum", 7, 3, 1))
            };
            publisher.send_copy(r).unwrap();
        }
        let mut epochs = vec![];
        while let Some(r) = subscriber.receive().unwrap() {
            epochs.push(r.payload().epoch);
        }
        assert_eq!(epochs, (0..n as u64).collect::<Vec<_>>());
    }

    #[test]
    fn waiting_for_a_wake_up_sleeps_until_one_comes_or_the_timeout() {
        use std::time::{Duration, Instant};
        let svc = Services::new(&run_id("wait"));
        let node = services::node(&learner_node_name(&svc.run_id)).unwrap();
        let event = services::to_learner(&node, &svc, 1).unwrap();
        let listener = event.listener_builder().create().unwrap();
        let notifier = event.notifier_builder().create().unwrap();
        let start = Instant::now();
        wait_for_wake(&listener, Duration::from_millis(200)).unwrap();
        assert!(
            start.elapsed() >= Duration::from_millis(190),
            "nothing came: it waits out the timeout ({:?})",
            start.elapsed()
        );
        notifier.notify().unwrap();
        let start = Instant::now();
        wait_for_wake(&listener, Duration::from_secs(10)).unwrap();
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "a wake-up ends the wait"
        );
    }
}

/// Opening the run's services with the same settings on both sides (iceoryx2 checks they agree).
///
/// A worker's side of the transitions service, and the learner's, in one process for brevity
/// ([`WorkerPorts::open`] and [`LearnerPorts::open`] each open their side, with these):
///
/// ```no_run
/// use selkd_protocol::{services, Services, TransitionHeader, TransitionRow, TRANSITION_BUFFER};
///
/// # fn main() -> Result<(), services::Error> {
/// let svc = Services::new("demo"); // the run id: both sides must use the same one
/// let actors = 2;
/// let row = TransitionRow { obs_dim: 3, act_dim: 1 };
///
/// // The learner subscribes (it also listens on `to_learner` to be woken).
/// let learner = services::node(&selkd_protocol::learner_node_name("demo"))?;
/// let subscriber = services::transitions(&learner, &svc, actors)?
///     .subscriber_builder()
///     .buffer_size(TRANSITION_BUFFER)
///     .create()?;
///
/// // A worker publishes one transition and wakes the learner.
/// let worker = services::node("actor-worker-0")?;
/// let publisher = services::transitions(&worker, &svc, actors)?
///     .publisher_builder()
///     .initial_max_slice_len(row.len())
///     .create()?;
/// let wake = services::to_learner(&worker, &svc, actors)?.notifier_builder().create()?;
/// let mut buf = Vec::new();
/// row.write(&mut buf, &[1.0, 0.0, 0.5], &[0.25], -0.3, &[0.99, 0.1, 0.4], false, false);
/// let mut sample = publisher.loan_slice_uninit(row.len())?;
/// *sample.user_header_mut() = TransitionHeader {
///     worker: 0,
///     obs_dim: 3,
///     act_dim: 1,
///     episode_return: f64::NAN, // not the episode's last step
///     ..Default::default()
/// };
/// sample.write_from_slice(&buf).send()?;
/// wake.notify()?;
///
/// while let Some(t) = subscriber.receive()? {
///     let (s, a, r, s2, terminated, _truncated) = row.split(t.payload());
///     println!("worker {}: {s:?} {a:?} {r} {s2:?} {terminated}", t.user_header().worker);
/// }
/// # Ok(())
/// # }
/// ```
pub mod services {
    use super::*;
    use iceoryx2::service::port_factory::{event, publish_subscribe};

    pub type Node = iceoryx2::node::Node<ipc::Service>;
    pub type PubSub<P, H = ()> = publish_subscribe::PortFactory<ipc::Service, P, H>;
    pub type Event = event::PortFactory<ipc::Service>;
    pub type Error = Box<dyn std::error::Error + Send + Sync>;
    pub type Publisher<P, H = ()> = iceoryx2::port::publisher::Publisher<ipc::Service, P, H>;
    pub type Subscriber<P, H = ()> = iceoryx2::port::subscriber::Subscriber<ipc::Service, P, H>;
    pub type Notifier = iceoryx2::port::notifier::Notifier<ipc::Service>;
    pub type Listener = iceoryx2::port::listener::Listener<ipc::Service>;

    /// A node that leaves signals to the process (the launcher manages them).
    pub fn node(name: &str) -> Result<Node, Error> {
        // iceoryx2's own warnings (e.g. "no config file loaded") are noise to users; keep errors.
        set_log_level_from_env_or(LogLevel::Error);
        Ok(NodeBuilder::new()
            .name(&NodeName::new(name)?)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()?)
    }

    pub fn transitions(
        node: &Node,
        s: &Services,
        actors: usize,
    ) -> Result<PubSub<[f32], TransitionHeader>, Error> {
        Ok(node
            .service_builder(&s.transitions()?)
            .publish_subscribe::<[f32]>()
            .user_header::<TransitionHeader>()
            .max_nodes(max_ports(actors))
            .max_publishers(max_ports(actors))
            .max_subscribers(2)
            .subscriber_max_buffer_size(TRANSITION_BUFFER)
            .history_size(0)
            .enable_safe_overflow(false)
            .open_or_create()?)
    }

    pub fn reports(node: &Node, s: &Services, actors: usize) -> Result<PubSub<Report>, Error> {
        Ok(node
            .service_builder(&s.reports()?)
            .publish_subscribe::<Report>()
            .max_nodes(max_ports(actors))
            .max_publishers(max_ports(actors))
            .max_subscribers(2)
            .subscriber_max_buffer_size(4 * MAX_ACTORS)
            .history_size(0)
            .enable_safe_overflow(false)
            .open_or_create()?)
    }

    /// "Latest value" services: history 1, and a slow reader only ever misses stale values.
    macro_rules! latest {
        ($node:expr, $name:expr, $payload:ty) => {
            $node
                .service_builder(&$name)
                .publish_subscribe::<$payload>()
                .max_nodes(MAX_ACTORS * 2 + 4)
                .max_publishers(2)
                .max_subscribers(MAX_ACTORS * 2 + 4)
                .history_size(1)
                .subscriber_max_buffer_size(1)
                .enable_safe_overflow(true)
        };
    }

    pub fn weights(
        node: &Node,
        s: &Services,
        actor: usize,
    ) -> Result<PubSub<[f32], WeightsHeader>, Error> {
        Ok(latest!(node, s.weights(actor)?, [f32])
            .user_header::<WeightsHeader>()
            .open_or_create()?)
    }

    pub fn cursor(
        node: &Node,
        s: &Services,
        actor: usize,
    ) -> Result<PubSub<[f32], CursorHeader>, Error> {
        Ok(latest!(node, s.cursor(actor)?, [f32])
            .user_header::<CursorHeader>()
            .open_or_create()?)
    }

    pub fn control(node: &Node, s: &Services) -> Result<PubSub<Control>, Error> {
        Ok(latest!(node, s.control()?, Control).open_or_create()?)
    }

    pub fn ranking(node: &Node, s: &Services) -> Result<PubSub<Ranking>, Error> {
        Ok(latest!(node, s.ranking()?, Ranking).open_or_create()?)
    }

    pub fn to_learner(node: &Node, s: &Services, actors: usize) -> Result<Event, Error> {
        Ok(node
            .service_builder(&s.to_learner()?)
            .event()
            .max_nodes(max_ports(actors) + 2)
            .max_notifiers(max_ports(actors) + 2)
            .max_listeners(2)
            .open_or_create()?)
    }

    pub fn to_workers(node: &Node, s: &Services) -> Result<Event, Error> {
        Ok(node
            .service_builder(&s.to_workers()?)
            .event()
            .max_nodes(MAX_ACTORS * 2 + 4)
            .max_notifiers(2)
            .max_listeners(MAX_ACTORS * 2 + 4)
            .open_or_create()?)
    }
}

/// Sleeps until a notification arrives on `listener` or `timeout` passes. A signal that cuts the
/// wait short (Ctrl-C, SIGTERM) is a wake-up like any other, not an error: the caller's loop then
/// sees its stop flag and shuts down cleanly.
pub fn wait_for_wake(
    listener: &services::Listener,
    timeout: std::time::Duration,
) -> Result<(), iceoryx2::port::listener::ListenerWaitError> {
    use iceoryx2::port::listener::ListenerWaitError;
    match listener.timed_wait(|_| {}, timeout) {
        Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(()),
        Err(e) => Err(e),
    }
}

/// The learner's iceoryx2 node name; workers watch for it to notice a learner that is gone.
pub fn learner_node_name(run_id: &str) -> String {
    format!("learner-{run_id}")
}

/// A worker's iceoryx2 node name: the learner looks for it to tell a worker that is gone (its
/// grant can go to the others) from one that is only quiet. Cut to iceoryx2's 128 bytes.
pub fn worker_node_name(run_id: &str, worker: usize) -> String {
    let mut name = format!("actor-worker-{worker}-{run_id}");
    let mut end = name.len().min(128);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    name.truncate(end);
    name
}

/// A worker's exit code for "this worker cannot join this run" (handshake mismatch, bad
/// arguments): restarting it would not help, so the launcher fails the run instead.
pub const EXIT_CANNOT_JOIN: i32 = 2;

/// Logs of the learner and the workers go to stderr (the launcher sends them to files), at
/// `RUST_LOG`'s levels or `info`; coloured only on a terminal.
pub fn init_tracing() {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .init();
}
