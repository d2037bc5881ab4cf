//! Kinematics benchmarks: ns per call of IK, FK, and J⁻¹ + Λ, over a fixed set of
//! workspace poses. Run with `cargo bench -p h4-shared --bench kinematics`.

use std::hint::black_box;
use std::time::Instant;

use h4_shared::{ActuatorStiffness, H4Params, Pose};
use nalgebra::Vector4;

fn poses() -> Vec<Pose> {
    let mut rng = h4_shared::rng::Rng::new(7);
    let p = H4Params::PROTOTYPE;
    let mut out = Vec::new();
    while out.len() < 1024 {
        let pose = Vector4::new(
            rng.uniform_in(-200.0, 200.0),
            rng.uniform_in(-150.0, 150.0),
            rng.uniform_in(-350.0, -50.0),
            rng.uniform_in(-1.0, 1.0),
        );
        if p.ik_checked(&pose).is_ok() {
            out.push(pose);
        }
    }
    out
}

/// Runs `f` over the inputs for at least 0.5 s and returns ns per call (best of 5 rounds).
fn bench<T>(name: &str, inputs: &[T], mut f: impl FnMut(&T) -> f64) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let start = Instant::now();
        let mut calls = 0u64;
        let mut sink = 0.0;
        while start.elapsed().as_secs_f64() < 0.1 {
            for x in inputs {
                sink += f(x);
            }
            calls += inputs.len() as u64;
        }
        black_box(sink);
        best = best.min(start.elapsed().as_nanos() as f64 / calls as f64);
    }
    println!("{name:<28} {best:>8.1} ns/call");
    best
}

fn main() {
    let p = H4Params::PROTOTYPE;
    let k = ActuatorStiffness::uniform(100.0).unwrap_or_else(|e| panic!("{e}"));
    let poses = poses();
    let ls: Vec<_> = poses.iter().filter_map(|q| p.ik_checked(q).ok()).collect();
    bench("ik_checked", &poses, |q| {
        black_box(&p).ik_checked(black_box(q)).map_or(0.0, |l| l[0])
    });
    bench("fk", &ls, |l| {
        black_box(&p).fk(black_box(l)).map_or(0.0, |q| q[2])
    });
    bench("jacobian", &poses, |q| {
        black_box(&p)
            .jacobian(black_box(q))
            .map_or(0.0, |j| j[(0, 1)])
    });
    bench("jacobian_inverse + compliance", &poses, |q| {
        black_box(&p)
            .compliance(black_box(q), &k)
            .map_or(0.0, |m| m[(1, 1)])
    });
}
