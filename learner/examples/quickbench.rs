fn main() {
    let k: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(1);
    let sharing = std::env::args().nth(2).unwrap_or("per-update".into());
    tch::set_num_threads(2);
    selkd_learner::keep_freed_memory();
    let mut cfg = selkd_learner::config::AlgoConfig::default();
    cfg.actors = k;
    cfg.sharing = if sharing == "per-critic" {
        selkd_learner::config::Sharing::PerCritic
    } else {
        selkd_learner::config::Sharing::PerUpdate
    };
    let r = selkd_learner::bench::learner(&cfg, 27, 8, tch::Device::Cpu, 10);
    println!(
        "K={k} {sharing}: {:.1} updates/s, {:.2} rounds/s",
        r.critic_updates_per_sec, r.rounds_per_sec
    );
}
