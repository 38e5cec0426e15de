//! Rate limiting for the async mode (SPEC "Rounds and env steps"): G critic updates per K
//! transitions after warm-up, with whichever side is ahead made to wait, as Reverb's
//! `SampleToInsertRatio` does. The learner never trains ahead of the data; workers may run ahead
//! of the updates by at most `tolerance` critic updates' worth of transitions.

pub struct RateLimiter {
    actors: u64,
    utd: u64,
    warmup_total: u64,
    tolerance_rounds: u64,
    /// Training starts (again) once `inserted` reaches this, with `base_rounds` rounds done
    /// before: the warm-up's end, or a refill's after a resume without the replay buffer.
    warmup_end: u64,
    base_rounds: u64,
    /// Where a refill began (`inserted` at the resume); its transitions pay for no round.
    refill_from: Option<u64>,
}

impl RateLimiter {
    /// `warmup_total`: transitions (all actors) before the first round; `tolerance`: in critic updates.
    pub fn new(actors: usize, utd: usize, warmup_total: u64, tolerance: f64) -> Self {
        let tolerance_rounds = ((tolerance / utd as f64).ceil() as u64).max(1);
        Self {
            actors: actors as u64,
            utd: utd as u64,
            warmup_total,
            tolerance_rounds,
            warmup_end: warmup_total,
            base_rounds: 0,
            refill_from: None,
        }
    }

    /// A resumed run whose checkpoint held no replay buffer: no training until another warm-up's
    /// worth of transitions (at least one) is stored after `inserted`, then G per K as before.
    /// `rounds_done` are the rounds the checkpoint had done.
    pub fn refill(&mut self, inserted: u64, rounds_done: u64) {
        self.warmup_end = inserted + self.warmup_total.max(1);
        self.base_rounds = rounds_done;
        self.refill_from = Some(inserted);
    }

    /// Whether the replay buffer holds enough to train on: the warm-up (or the refill) is over.
    pub fn warmed_up(&self, inserted: u64) -> bool {
        inserted >= self.warmup_end
    }

    /// `inserted` when training starts (again): the warm-up's end, or the refill's.
    pub fn warmup_end(&self) -> u64 {
        self.warmup_end
    }

    /// Training rounds (G critic updates + one actor update each) that `inserted` transitions pay for:
    /// one when warm-up completes, then one per K further transitions (after a refill: the
    /// checkpoint's rounds, then the same).
    pub fn rounds_due(&self, inserted: u64) -> u64 {
        if inserted < self.warmup_end {
            self.base_rounds
        } else {
            self.base_rounds + (inserted - self.warmup_end) / self.actors + 1
        }
    }

    /// How many more transitions (all workers together) may arrive before the workers would be
    /// more than the tolerance ahead of `rounds_done`.
    pub fn insert_allowance(&self, inserted: u64, rounds_done: u64) -> u64 {
        let ahead = rounds_done.saturating_sub(self.base_rounds) + self.tolerance_rounds;
        let limit = self.warmup_end + ahead * self.actors;
        limit.saturating_sub(inserted)
    }

    /// Critic updates per inserted transition after warm-up (a refill's transitions, like the
    /// warm-up's, not counted), and the target G/K.
    pub fn ratio(&self, critic_updates: u64, inserted: u64) -> (f64, f64) {
        let refill = self
            .refill_from
            .map_or(0, |from| inserted.clamp(from, self.warmup_end) - from);
        let after = inserted.saturating_sub(self.warmup_total + refill).max(1);
        (
            critic_updates as f64 / after as f64,
            self.utd as f64 / self.actors as f64,
        )
    }
}

/// Async mode's env-step grants: `granted[w]` is how far worker `w` may step (its rollout's
/// transition count), raised here, never lowered (a worker may already be using it). Grants are
/// topped up to an equal share of the limiter's `allowance` among the `takers` (the workers that
/// step or wait for more), so a worker that holds an unused grant but has gone quiet (killed and
/// waiting out its restart back-off, stopped, evaluating) leaves its share to the others instead
/// of stalling the run. What may still arrive never exceeds `allowance` (G per K holds overall),
/// and the grants never add up past `total` (the run takes exactly its budget). `first`: where
/// the round-robin starts, so remainders do not always go to worker 0.
pub fn top_up(
    granted: &mut [u64],
    sent: &[u64],
    takers: &[bool],
    allowance: u64,
    total: u64,
    first: usize,
) {
    let k = granted.len();
    let held = |g: &[u64], w: usize| g[w].saturating_sub(sent[w]);
    let outstanding: u64 = (0..k).map(|w| held(granted, w)).sum();
    let committed: u64 = (0..k).map(|w| granted[w].max(sent[w])).sum();
    let mut free = allowance
        .saturating_sub(outstanding)
        .min(total.saturating_sub(committed));
    let n = takers.iter().filter(|&&t| t).count() as u64;
    if n == 0 {
        return;
    }
    // Each taker's target: an equal part of what the takers may hold (the allowance less what
    // quiet workers hold, and no more than is left of the total).
    let held_by = |take: bool| -> u64 {
        (0..k)
            .filter(|&w| takers[w] == take)
            .map(|w| held(granted, w))
            .sum()
    };
    let share = allowance
        .saturating_sub(held_by(false))
        .min(free + held_by(true))
        .div_ceil(n);
    for i in 0..k {
        let w = (first + i) % k;
        if takers[w] && free > 0 {
            let add = share.saturating_sub(held(granted, w)).min(free);
            granted[w] = granted[w].max(sent[w]) + add;
            free -= add;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_round_per_k_transitions_after_warmup() {
        let r = RateLimiter::new(5, 20, 5000, 100.0);
        assert_eq!(r.rounds_due(4999), 0);
        assert_eq!(r.rounds_due(5000), 1);
        assert_eq!(r.rounds_due(5004), 1);
        assert_eq!(r.rounds_due(5005), 2);
        // Updates per transition settle at G/K.
        let inserted = 5000 + 5 * 1000;
        let (got, want) = r.ratio(20 * r.rounds_due(inserted), inserted);
        assert!((got - want).abs() / want < 0.01, "{got} vs {want}");
    }

    /// The reported ratio against hand values: critic updates per transition after warm-up
    /// (counted from one transition while none are), and G/K beside it.
    #[test]
    fn ratio_is_updates_per_transition_after_warmup_beside_g_over_k() {
        let r = RateLimiter::new(5, 20, 5000, 100.0);
        assert_eq!(r.ratio(2000, 6000), (2.0, 4.0));
        assert_eq!(r.ratio(3, 4000), (3.0, 4.0));
        assert_eq!(RateLimiter::new(2, 3, 10, 100.0).ratio(9, 16), (1.5, 1.5));
    }

    /// After a refill (resumed at 150 with warm-up 100, so transitions 150–250 refill the
    /// buffer), the ratio leaves the refill out, as it leaves out the warm-up: at 200, 50
    /// transitions have paid for rounds (100–150); at 300, 100 (100–150 and 250–300).
    #[test]
    fn the_ratio_after_a_refill_leaves_the_refill_out() {
        let mut r = RateLimiter::new(2, 20, 100, 100.0);
        r.refill(150, 7);
        assert_eq!(r.ratio(140, 200), (2.8, 10.0));
        assert_eq!(r.ratio(140, 250), (2.8, 10.0));
        assert_eq!(r.ratio(660, 300), (6.6, 10.0));
    }

    #[test]
    fn workers_wait_when_the_learner_falls_behind_by_the_tolerance() {
        let r = RateLimiter::new(2, 20, 100, 100.0); // tolerance 100 updates = 5 rounds
        assert_eq!(r.insert_allowance(0, 0), 110);
        // Learner has done 3 rounds; workers have sent 100 + 2·8 transitions: 8 rounds' worth.
        assert_eq!(r.insert_allowance(116, 3), 0);
        assert_eq!(r.insert_allowance(110, 3), 6);
    }

    /// Resumed at 150 transitions with 7 rounds done and an empty replay buffer: no round is due
    /// until 100 more are in (250), then the 8th at once and one per K = 2 after it; meanwhile
    /// the workers may send the whole refill plus the tolerance (5 rounds of 2).
    #[test]
    fn a_refill_after_a_resume_trains_again_only_after_another_warm_up() {
        let mut r = RateLimiter::new(2, 20, 100, 100.0);
        r.refill(150, 7);
        assert!(!r.warmed_up(249) && r.warmed_up(250));
        assert_eq!(r.warmup_end(), 250);
        assert_eq!(r.rounds_due(150), 7);
        assert_eq!(r.rounds_due(249), 7);
        assert_eq!(r.rounds_due(250), 8);
        assert_eq!(r.rounds_due(255), 10);
        assert_eq!(r.insert_allowance(150, 7), 110);
        assert_eq!(r.insert_allowance(258, 8), 4);
        // A run without warm-up still waits for one transition.
        let mut none = RateLimiter::new(2, 20, 0, 100.0);
        assert_eq!((none.rounds_due(0), none.warmed_up(0)), (1, true));
        none.refill(40, 21);
        assert_eq!((none.rounds_due(40), none.warmed_up(40)), (21, false));
        assert_eq!(none.rounds_due(41), 22);
    }

    /// Three workers, allowance 30, total 100: equal shares while all step; a quiet worker
    /// holding 10 unused keeps them, the two others share the rest; the grants stop at the total.
    #[test]
    fn grants_share_the_allowance_among_takers_and_never_pass_the_total() {
        let mut g = vec![0; 3];
        top_up(&mut g, &[0, 0, 0], &[true; 3], 30, 100, 0);
        assert_eq!(g, [10, 10, 10]);
        // Workers 1 and 2 used theirs; worker 0 went quiet with its 10 unused.
        let sent = [0, 10, 10];
        top_up(&mut g, &sent, &[false, true, true], 30, 100, 0);
        assert_eq!(
            g,
            [10, 20, 20],
            "only 20 more may arrive besides worker 0's 10"
        );
        let sent = [0, 20, 20];
        top_up(&mut g, &sent, &[false, true, true], 30, 100, 1);
        assert_eq!(g, [10, 30, 30]);
        // Close to the total: 100 − 70 = 30 left, of which worker 0 holds 10.
        let sent = [0, 30, 30];
        top_up(&mut g, &sent, &[false, true, true], 60, 100, 0);
        assert_eq!(g, [10, 45, 45]);
        assert_eq!(g.iter().sum::<u64>(), 100);
        top_up(&mut g, &[0, 45, 45], &[false, true, true], 60, 100, 0);
        assert_eq!(g, [10, 45, 45], "nothing past the total");
        // Worker 0's grant taken back (it is gone): the others finish the run.
        g[0] = 0;
        top_up(&mut g, &[0, 45, 45], &[false, true, true], 60, 100, 0);
        assert_eq!(g, [0, 50, 50]);
    }

    /// A grant is never lowered, and nothing is granted while the workers hold the allowance.
    #[test]
    fn grants_in_use_are_kept_and_hold_the_allowance() {
        let mut g = vec![8, 8];
        top_up(&mut g, &[2, 2], &[true, true], 12, 1000, 0);
        assert_eq!(g, [8, 8], "12 may arrive and 12 are granted already");
        top_up(&mut g, &[2, 2], &[true, true], 4, 1000, 0);
        assert_eq!(g, [8, 8]);
        top_up(&mut g, &[8, 2], &[true, true], 12, 1000, 0);
        assert_eq!(g, [14, 8]);
    }
}
