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
fn main() {
    tch::set_num_threads(2);
    selkd_learner::keep_freed_memory();
    let mut rng = <rand_pcg::Pcg64 as rand::SeedableRng>::seed_from_u64(0);
    let critics = Ensemble::new(10, &[35, 256, 256, 1], Device::Cpu, &mut rng);
    let x = Tensor::randn([1, 256, 35], (Kind::Float, Device::Cpu));
    let y = Tensor::randn([1, 256, 1], (Kind::Float, Device::Cpu));
    time("autograd forward+backward", 100, || {
        let q = critics.forward(&x.expand([10, 256, 35], false));
        let loss = ((&q - &y).square() * 0.5)
            .mean_dim(1, false, Kind::Float)
            .sum(Kind::Float);
        loss.backward();
    });
    let p: Vec<Tensor> = critics.params().iter().map(|t| t.detach()).collect();
    time("manual forward+backward", 100, || {
        tch::no_grad(|| {
            let xe = x.expand([10, 256, 35], false);
            let h1 = p[1].baddbmm(&xe, &p[0], 1.0, 1.0).relu();
            let h2 = p[3].baddbmm(&h1, &p[2], 1.0, 1.0).relu();
            let q = p[5].baddbmm(&h2, &p[4], 1.0, 1.0);
            let dq = (q - &y) / 256.0;
            let _gw3 = h2.transpose(1, 2).bmm(&dq);
            let _gb3 = dq.sum_dim_intlist(1, true, Kind::Float);
            let dh2 = dq.bmm(&p[4].transpose(1, 2)) * h2.gt(0.0);
            let _gw2 = h1.transpose(1, 2).bmm(&dh2);
            let _gb2 = dh2.sum_dim_intlist(1, true, Kind::Float);
            let dh1 = dh2.bmm(&p[2].transpose(1, 2)) * h1.gt(0.0);
            let _gw1 = xe.transpose(1, 2).bmm(&dh1);
            let _gb1 = dh1.sum_dim_intlist(1, true, Kind::Float);
        })
    });
    let w2 = Tensor::randn([10, 256, 256], (Kind::Float, Device::Cpu));
    let h = Tensor::randn([10, 256, 256], (Kind::Float, Device::Cpu));
    time("3 bmm 10x256^3 only", 100, || {
        let _a = h.bmm(&w2);
        let _b = h.transpose(1, 2).bmm(&h);
        let _c = h.bmm(&w2.transpose(1, 2));
    });
}
