//! The SELKD learner: it holds the N critics and the K actors' training copies, stores every
//! worker's transitions in one replay buffer, computes the in-target max-min targets, trains, and
//! hands back weights and the Monte-Carlo ranking that picks the actor everyone distils toward.
//!
//! The algorithm itself reads top to bottom in [`selkd`]; each concept it uses has its own module.

pub mod config;
pub mod distillation;
pub mod ensemble;
pub mod optim;
pub mod replay;
pub mod selkd;
pub mod squashed_gaussian;
pub mod targets;
pub mod bench;
pub mod checkpoint;
pub mod ranking;
pub mod rate_limit;
pub mod service;
