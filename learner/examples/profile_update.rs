//! Times the pieces of one critic-ensemble update at the benchmark's sizes (a profiling aid).
use selkd_learner::ensemble::Ensemble;
use std::time::Instant;
use tch::{Device, Kind, Tensor};
fn time(name: &str, n: usize, mut f: impl FnMut()) {
    f();
    let t0 = Instant::now();
    for _ in 0..n {
        f();
    }
    println!(
        "{name}: {:.3} ms",
        t0.elapsed().as_secs_f64() * 1000.0 / n as f64
    );
}
fn forward(e: &Ensemble, x: &Tensor, kind: Kind) -> Tensor {
    let last = e.layers.len() - 1;
    let mut h = x.to_kind(kind);
    for (l, layer) in e.layers.iter().enumerate() {
        h = layer
            .bias
            .to_kind(kind)
            .baddbmm(&h, &layer.weight.to_kind(kind), 1.0, 1.0);
        if l < last {
            h = h.relu();
        }
    }
    h.to_kind(Kind::Float)
}
fn main() {
    tch::set_num_threads(2);
    selkd_learner::keep_freed_memory();
    let mut rng = <rand_pcg::Pcg64 as rand::SeedableRng>::seed_from_u64(0);
    let critics = Ensemble::new(10, &[35, 256, 256, 1], Device::Cpu, &mut rng);
    let x = Tensor::randn([1, 256, 35], (Kind::Float, Device::Cpu));
    let y = Tensor::randn([1, 256, 1], (Kind::Float, Device::Cpu));
    for kind in [Kind::Float, Kind::BFloat16] {
        time(&format!("{kind:?} forward+backward"), 100, || {
            let q = forward(&critics, &x.expand([10, 256, 35], false), kind);
            let loss = ((&q - &y).square() * 0.5)
                .mean_dim(1, false, Kind::Float)
                .sum(Kind::Float);
            loss.backward();
        });
    }
}
