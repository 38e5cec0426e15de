"""Issue 32, docs/results/fidelity.md: Gymnasium's MuJoCo half_cheetah.xml flailing the sine gait
(envs/src/gaits.rs HALFCHEETAH) 50 m above the floor for 1 s from rest, at 10, 1 and 0.1 ms steps:
how far the torso drifts along x (its horizontal momentum must stay zero). Our side of the
comparison: `cargo test --release -p selkd-envs fidelity::cheetah_in_air -- --ignored --nocapture`.
Run with the project venv's python (mujoco, gymnasium)."""
import mujoco, numpy as np, os, gymnasium
xml = os.path.join(os.path.dirname(gymnasium.__file__), "envs/mujoco/assets/half_cheetah.xml")
p = [4.22699, -2.7452831, 1.0884578, -1.0541096, 0.44694817, -2.9582198, 1.9110123]
for dt, skip in [(0.01,5),(0.001,50),(0.0001,500)]:
    m = mujoco.MjModel.from_xml_path(xml); m.opt.timestep = dt
    d = mujoco.MjData(m); d.qpos[1] = 50.0
    mujoco.mj_forward(m, d)
    for t in range(20):
        ph = 2*np.pi*p[0]*t*0.05
        d.ctrl[:] = [np.sin(ph+p[1+j]) for j in range(6)]
        for _ in range(skip): mujoco.mj_step(m, d)
    print(dt, np.round(d.qpos,3), np.round(d.qvel,2))
