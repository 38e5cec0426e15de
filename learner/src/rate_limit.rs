//! Rate limiting for the async mode (SPEC "Rounds and env steps"): G critic updates per K
//! transitions after warm-up, with whichever side is ahead made to wait, as Reverb's
//! `SampleToInsertRatio` does. The learner never trains ahead of the data; workers may run ahead
//! of the updates by at most `tolerance` critic updates' worth of transitions.

pub struct RateLimiter {
    actors: u64,
    utd: u64,
    warmup_total: u64,
    tolerance_rounds: u64,
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
        }
    }

    /// Training rounds (G critic updates + one actor update each) that `inserted` transitions pay for:
    /// one when warm-up completes, then one per K further transitions.
    pub fn rounds_due(&self, inserted: u64) -> u64 {
        if inserted < self.warmup_total {
            0
        } else {
            (inserted - self.warmup_total) / self.actors + 1
        }
    }

    /// How many more transitions (all workers together) may arrive before the workers would be
    /// more than the tolerance ahead of `rounds_done`.
    pub fn insert_allowance(&self, inserted: u64, rounds_done: u64) -> u64 {
        let limit = self.warmup_total + (rounds_done + self.tolerance_rounds) * self.actors;
        limit.saturating_sub(inserted)
    }

    /// Critic updates per inserted transition after warm-up, and the target G/K.
    pub fn ratio(&self, critic_updates: u64, inserted: u64) -> (f64, f64) {
        let after = inserted.saturating_sub(self.warmup_total).max(1);
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

    #[test]
    fn workers_wait_when_the_learner_falls_behind_by_the_tolerance() {
        let r = RateLimiter::new(2, 20, 100, 100.0); // tolerance 100 updates = 5 rounds
        assert_eq!(r.insert_allowance(0, 0), 110);
        // Learner has done 3 rounds; workers have sent 100 + 2·8 transitions: 8 rounds' worth.
        assert_eq!(r.insert_allowance(116, 3), 0);
        assert_eq!(r.insert_allowance(110, 3), 6);
    }
}
