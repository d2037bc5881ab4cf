//! The cut's cost per 1 ms cycle at the default grid (0.25 mm cells over 150 × 150 mm): the
//! removal update ([`CutState::update`]: the sweep of the stock along the tip's path and the
//! engagement the next servo periods cut with) with a 3 mm ball end feeding at 10 mm/s 2 mm
//! deep in resin, then the whole simulated arm's millisecond (20 servo periods) cutting and
//! touching a plane. Run with `cargo bench -p h4-slave-sim --bench cutting`.
#![allow(clippy::expect_used)]

use std::hint::black_box;
use std::time::Instant;

use h4_shared::kinematics::{H4Params, Pose};
use h4_slave::arm::ArmDriver;
use h4_slave_sim::plant::cutting::{CutState, CuttingConfig};
use h4_slave_sim::plant::{
    Material, MaterialPreset, PlantConfig, SensorConfig, SimArm, Surface, SurfaceShape,
};

/// µs per call of `f(k)` over `n` calls (best of 5 rounds).
fn bench(name: &str, n: u32, mut setup: impl FnMut() -> Box<dyn FnMut(u32)>) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let mut f = setup();
        let start = Instant::now();
        for k in 0..n {
            f(k);
        }
        best = best.min(start.elapsed().as_secs_f64() * 1e6 / f64::from(n));
    }
    println!("{name}: {best:.2} µs per 1 ms cycle");
    best
}

fn main() {
    let cfg = CuttingConfig::default();
    let top = cfg.stock_centre_top_mm[2];
    bench("removal update (sweep + engagement)", 20_000, || {
        let mut cut = CutState::new(&cfg, [-60.0, 0.0, top - 2.0]).expect("stock");
        Box::new(move |k| {
            // 10 mm/s along x: 0.01 mm per cycle, 2 mm deep.
            cut.update([-60.0 + 0.01 * f64::from(k), 0.0, top - 2.0]);
            black_box(cut.report());
        })
    });
    let params = H4Params::PROTOTYPE;
    let surface = Surface {
        shape: SurfaceShape::Plane {
            point_mm: [0.0, 0.0, top],
            normal: [0.0, 0.0, 1.0],
        },
        material: Material {
            ..MaterialPreset::Resin.material()
        },
    };
    for (name, cutting) in [("arm, 1 ms, cutting", true), ("arm, 1 ms, plane", false)] {
        bench(name, 3000, || {
            let arm = SimArm::new(
                params,
                [100.0; 4],
                PlantConfig::default(),
                SensorConfig::default(),
                surface,
                Pose::new(-10.0, 0.0, top + 0.5, 0.0),
                1,
            )
            .expect("arm");
            let mut arm = if cutting {
                arm.with_cutting(&cfg).expect("cut")
            } else {
                arm
            };
            Box::new(move |k| {
                let x = -10.0 + 0.01 * f64::from(k);
                let z = if cutting { top - 2.0 } else { top - 0.05 };
                if let Ok(l) = params.ik_checked(&Pose::new(x, 0.0, z, 0.0)) {
                    arm.command(&[l[0], l[1], l[2], l[3]]);
                }
                arm.advance(1_000_000);
                black_box(arm.read());
            })
        });
    }
}
