//! The replay buffer D shared by all actors: FIFO, fixed capacity, uniform sampling.
//!
//! Rows `[s, a, r, s', terminated]` live in one `[capacity, width]` tensor on the training device,
//! so a mini-batch is one gather. Inserts are staged on the host and written in one copy before
//! the next sample.

use rand::Rng;
use tch::{Device, Kind, Tensor};

pub struct ReplayBuffer {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    data: Tensor,
    /// Next row to write.
    cursor: usize,
    len: usize,
    staged: Vec<f32>,
    staged_rows: usize,
    /// Transitions ever inserted (the FIFO's total count, for reporting).
    pub inserted: u64,
}

/// A mini-batch, `G` groups of `B` rows: `obs [G,B,obs]`, `act [G,B,act]`, `reward [G,B]`,
/// `next_obs [G,B,obs]`, `terminated [G,B]` (0/1).
pub struct Batch {
    pub obs: Tensor,
    pub act: Tensor,
    pub reward: Tensor,
    pub next_obs: Tensor,
    pub terminated: Tensor,
}

impl Batch {
    /// The same rows (tensors share storage; a batch is never written to).
    pub fn shallow_clone(&self) -> Batch {
        Batch {
            obs: self.obs.shallow_clone(),
            act: self.act.shallow_clone(),
            reward: self.reward.shallow_clone(),
            next_obs: self.next_obs.shallow_clone(),
            terminated: self.terminated.shallow_clone(),
        }
    }
}

impl ReplayBuffer {
    pub fn new(capacity: usize, obs_dim: usize, act_dim: usize, device: Device) -> Self {
        let width = Self::width_for(obs_dim, act_dim);
        Self {
            obs_dim,
            act_dim,
            capacity,
            data: Tensor::zeros([capacity as i64, width as i64], (Kind::Float, device)),
            cursor: 0,
            len: 0,
            staged: Vec::new(),
            staged_rows: 0,
            inserted: 0,
        }
    }

    fn width_for(obs_dim: usize, act_dim: usize) -> usize {
        2 * obs_dim + act_dim + 2
    }

    pub fn len(&self) -> usize {
        self.len + self.staged_rows.min(self.capacity - self.len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Stores one transition. The caller has checked sizes and finiteness.
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        debug_assert_eq!(
            (obs.len(), act.len(), next_obs.len()),
            (self.obs_dim, self.act_dim, self.obs_dim)
        );
        self.staged.extend_from_slice(obs);
        self.staged.extend_from_slice(act);
        self.staged.push(reward);
        self.staged.extend_from_slice(next_obs);
        self.staged.push(terminated as u8 as f32);
        self.staged_rows += 1;
        self.inserted += 1;
        if self.staged_rows >= 4096 {
            self.flush();
        }
    }

    /// Writes staged rows into the ring (wrapping, oldest overwritten first).
    pub fn flush(&mut self) {
        if self.staged_rows == 0 {
            return;
        }
        let width = Self::width_for(self.obs_dim, self.act_dim);
        let mut rows = self.staged_rows;
        let mut src = &self.staged[..];
        // More rows than capacity: only the newest `capacity` survive.
        if rows > self.capacity {
            src = &src[(rows - self.capacity) * width..];
            rows = self.capacity;
        }
        let mut done = 0;
        while done < rows {
            let n = (rows - done).min(self.capacity - self.cursor);
            let chunk = Tensor::from_slice(&src[done * width..(done + n) * width])
                .view([n as i64, width as i64]);
            self.data
                .narrow(0, self.cursor as i64, n as i64)
                .copy_(&chunk);
            self.cursor = (self.cursor + n) % self.capacity;
            done += n;
        }
        self.len = (self.len + rows).min(self.capacity);
        self.staged.clear();
        self.staged_rows = 0;
    }

    /// `groups` independent mini-batches of `batch` rows each, uniformly with replacement.
    pub fn sample(&mut self, groups: usize, batch: usize, rng: &mut impl Rng) -> Batch {
        self.flush();
        assert!(self.len > 0, "sample from an empty replay buffer");
        let idx: Vec<i64> = (0..groups * batch)
            .map(|_| rng.gen_range(0..self.len) as i64)
            .collect();
        let idx = Tensor::from_slice(&idx).to_device(self.data.device());
        let rows = self
            .data
            .index_select(0, &idx)
            .view([groups as i64, batch as i64, -1]);
        let (o, a) = (self.obs_dim as i64, self.act_dim as i64);
        Batch {
            obs: rows.narrow(2, 0, o),
            act: rows.narrow(2, o, a),
            reward: rows.narrow(2, o + a, 1).squeeze_dim(2),
            next_obs: rows.narrow(2, o + a + 1, o),
            terminated: rows.narrow(2, 2 * o + a + 1, 1).squeeze_dim(2),
        }
    }

    /// All stored rows, oldest first, as `[len, width]` (for checkpoints).
    pub fn export(&mut self) -> Tensor {
        self.flush();
        if self.len < self.capacity {
            self.data.narrow(0, 0, self.len as i64).copy()
        } else {
            Tensor::cat(
                &[
                    self.data
                        .narrow(0, self.cursor as i64, (self.capacity - self.cursor) as i64),
                    self.data.narrow(0, 0, self.cursor as i64),
                ],
                0,
            )
        }
    }

    /// Restores rows written by [`export`](Self::export).
    pub fn import(&mut self, rows: &Tensor) {
        let n = rows.size()[0].min(self.capacity as i64);
        let start = rows.size()[0] - n;
        self.data
            .narrow(0, 0, n)
            .copy_(&rows.narrow(0, start, n).to_device(self.data.device()));
        self.len = n as usize;
        self.cursor = (n as usize) % self.capacity;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn fifo_keeps_the_newest_capacity_rows_and_splits_fields() {
        let mut rb = ReplayBuffer::new(5, 3, 1, Device::Cpu);
        for i in 0..8 {
            let f = i as f32;
            rb.push(
                &[f, f + 0.5, f + 0.25],
                &[-f],
                10.0 * f,
                &[f + 1.0, f + 1.5, f + 1.75],
                i % 2 == 1,
            );
        }
        assert_eq!(rb.len(), 5);
        let rows = Vec::<f32>::try_from(rb.export().select(1, 0)).unwrap();
        assert_eq!(rows, vec![3.0, 4.0, 5.0, 6.0, 7.0], "oldest evicted first");
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        let b = rb.sample(2, 16, &mut rng);
        // Three observation entries: with two, 2·obs and obs + 2 coincide and a wrong offset of
        // the terminated column would go unseen.
        assert_eq!(b.obs.size(), vec![2, 16, 3]);
        for g in 0..2 {
            for k in 0..16 {
                let s = b.obs.double_value(&[g, k, 0]);
                assert!((3.0..=7.0).contains(&s));
                assert_eq!(b.act.double_value(&[g, k, 0]), -s);
                assert_eq!(b.reward.double_value(&[g, k]), 10.0 * s);
                assert_eq!(b.obs.double_value(&[g, k, 2]), s + 0.25);
                assert_eq!(b.next_obs.double_value(&[g, k, 0]), s + 1.0);
                assert_eq!(b.next_obs.double_value(&[g, k, 2]), s + 1.75);
                assert_eq!(b.terminated.double_value(&[g, k]), (s as i64 % 2) as f64);
            }
        }
    }

    /// A flush whose staged rows run past the ring's end writes them in two pieces: the first up
    /// to the end, the rest from the start, each row where it belongs.
    #[test]
    fn a_flush_that_wraps_round_the_ring_keeps_every_row_in_order() {
        let mut rb = ReplayBuffer::new(10, 1, 1, Device::Cpu);
        let push = |rb: &mut ReplayBuffer, t: usize| {
            let v = t as f32;
            rb.push(&[v], &[-v], 0.5 * v, &[v + 0.25], t % 2 == 0);
        };
        (0..8).for_each(|t| push(&mut rb, t));
        rb.flush(); // cursor at 8
        (8..13).for_each(|t| push(&mut rb, t)); // 2 rows to the end, 3 from the start
        let rows = rb.export();
        assert_eq!(rows.size(), [10, 5]);
        for (i, t) in (3..13).enumerate() {
            let row = Vec::<f32>::try_from(rows.get(i as i64)).unwrap();
            let v = t as f32;
            assert_eq!(
                row,
                [v, -v, 0.5 * v, v + 0.25, (t % 2 == 0) as u8 as f32],
                "row {i}"
            );
        }
        assert_eq!(rb.len(), 10);
    }

    /// Rows wait in a staging area until a sample, an export or 4096 of them flush them; the
    /// counts must be right before that flush too (the learner reports them every round).
    #[test]
    #[allow(clippy::len_zero)] // `len` and `is_empty` are both under test
    fn staged_rows_count_before_they_are_flushed() {
        let mut rb = ReplayBuffer::new(5, 1, 1, Device::Cpu);
        assert!(rb.is_empty() && rb.len() == 0 && rb.capacity() == 5);
        for i in 0..3 {
            rb.push(&[i as f32], &[0.0], 0.0, &[0.0], false);
        }
        assert_eq!((rb.len(), rb.is_empty(), rb.inserted), (3, false, 3));
        for i in 3..9 {
            rb.push(&[i as f32], &[0.0], 0.0, &[0.0], false);
        }
        assert_eq!((rb.len(), rb.inserted), (5, 9), "len stops at the capacity");
        rb.flush();
        assert_eq!(rb.len(), 5);
        for i in 9..11 {
            rb.push(&[i as f32], &[0.0], 0.0, &[0.0], false);
        }
        assert_eq!((rb.len(), rb.inserted), (5, 11));
        assert_eq!(
            Vec::<f32>::try_from(rb.export().select(1, 0)).unwrap(),
            vec![6.0, 7.0, 8.0, 9.0, 10.0]
        );
    }

    #[test]
    fn export_then_import_restores_order() {
        let mut rb = ReplayBuffer::new(4, 1, 1, Device::Cpu);
        for i in 0..6 {
            rb.push(&[i as f32], &[0.0], 0.0, &[0.0], false);
        }
        let rows = rb.export();
        let mut other = ReplayBuffer::new(4, 1, 1, Device::Cpu);
        other.import(&rows);
        assert_eq!(
            Vec::<f32>::try_from(other.export().select(1, 0)).unwrap(),
            vec![2.0, 3.0, 4.0, 5.0]
        );
    }
}
