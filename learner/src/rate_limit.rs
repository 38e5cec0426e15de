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
}
