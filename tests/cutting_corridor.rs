//! The corridor fixture end to end: the operator strays from the planned path (a straight
//! line along x) by 4 mm in y; with a 0.5 mm corridor the slave's tool point, and so the cut,
//! stays within it, and without the corridor the cut follows the operator off the path.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::operator::IntentSegment;
use h4_master_sim::session::{self, Session};

/// The largest |y| of the tool's true position while it cuts (x between −8 and 8 mm), and the
/// largest |y| of a cell cut deeper than 0.5 mm.
fn stray(corridor: bool) -> (f64, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let mut cfg = session::load(&path, &["duration_s=8".to_string()]).unwrap();
    // The operator: down at (−10, 0), then along x drifting to y = 4 mm.
    let seg = |at_s: f64, target_mm: [f64; 3], move_s: f64, push_z: f64| IntentSegment {
        at_s,
        target_mm,
        move_s,
        push_n: [0.0, 0.0, push_z],
        push_ramp_s: 0.5,
        clutch: false,
        theta_rad: 0.0,
    };
    cfg.operator.intent = vec![
        seg(0.0, [-10.0, 0.0, 0.0], 1.0, 0.0),
        seg(1.2, [-10.0, 0.0, 0.0], 0.0, -5.0),
        seg(2.5, [10.0, 4.0, 0.0], 4.0, -5.0),
    ];
    // The corridor alone (not the pocket's region).
    cfg.fixtures.region = None;
    cfg.fixtures.corridor = corridor.then(|| h4_slave::controller::fixtures::CorridorConfig {
        path_mm: vec![[-12.0, 0.0], [12.0, 0.0]],
        half_width_mm: 0.5,
    });
    let mut s = Session::new(&cfg).unwrap();
    let worst = h4_tests::max_while_cutting(&mut s, 8000, -250.5, |p| {
        if p[0].abs() < 8.0 { p[1].abs() } else { 0.0 }
    });
    let stock = s.slave.arm().cut().unwrap().stock();
    let (nx, ny) = stock.dims();
    let mut cut_y: f64 = 0.0;
    for iy in 0..ny {
        for ix in 0..nx {
            if stock.height_at(ix, iy) < stock.top_mm() - 0.5 {
                cut_y = cut_y.max(stock.cell_centre_mm(ix, iy)[1].abs());
            }
        }
    }
    (worst, cut_y)
}

#[test]
fn the_corridor_keeps_the_cut_on_the_planned_path() {
    let (with, cut_with) = stray(true);
    let (without, cut_without) = stray(false);
    assert!(without > 2.5, "the operator did not stray: {without} mm");
    assert!(with <= 0.55, "with the corridor the tool strayed {with} mm");
    // The cut is the tool's width (3 mm radius) around where the tool went.
    assert!(
        cut_with <= 3.0 + 0.55 + 0.25,
        "cut {cut_with} mm off the path"
    );
    assert!(cut_without > cut_with + 2.0, "{cut_without} vs {cut_with}");
}

/// The distance of `q` (x, y) from the polyline `path`, mm.
fn off_path_mm(path: &[[f64; 2]], q: [f64; 2]) -> f64 {
    path.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let ab = [b[0] - a[0], b[1] - a[1]];
            let len2 = ab[0] * ab[0] + ab[1] * ab[1];
            let t = (((q[0] - a[0]) * ab[0] + (q[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0);
            (q[0] - a[0] - t * ab[0]).hypot(q[1] - a[1] - t * ab[1])
        })
        .fold(f64::INFINITY, f64::min)
}

/// The shipped guided session (`config/sessions/cut-slot-guided.toml`): an L-shaped slot
/// whose operator strays 2 mm off the first leg and 2 mm past the corner. While the tool
/// cuts (tip 0.5 mm below the top) its true point stays within the 0.3 mm corridor (+ the
/// servo's lag: 0.35 mm asserted), the slot is cut along both legs, and the floor holds.
/// Control: without the corridor the same hand takes the tool more than 1.5 mm off the path.
#[test]
fn the_shipped_guided_slot_follows_its_corridor() {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-slot-guided.toml");
    let run = |corridor: bool| -> (f64, f64, session::Summary) {
        let mut cfg = session::load(&path, &[]).unwrap();
        let plan = cfg.fixtures.corridor.clone().unwrap().path_mm;
        if !corridor {
            cfg.fixtures.corridor = None;
        }
        let mut s = Session::new(&cfg).unwrap();
        let worst = h4_tests::max_while_cutting(&mut s, 16_000, -250.5, |p| {
            off_path_mm(&plan, [p[0], p[1]])
        });
        // The slot reaches the end of the second leg: a cell at (10, 4) cut 0.8 mm deep.
        let stock = s.slave.arm().cut().unwrap().stock();
        let (nx, ny) = stock.dims();
        let mut end_depth: f64 = 0.0;
        for iy in 0..ny {
            for ix in 0..nx {
                let c = stock.cell_centre_mm(ix, iy);
                if (c[0] - 10.0).abs() < 0.2 && (c[1] - 4.0).abs() < 0.2 {
                    end_depth = end_depth.max(stock.top_mm() - stock.height_at(ix, iy));
                }
            }
        }
        (worst, end_depth, session::run(&cfg, None).unwrap())
    };
    let (with, end_depth, summary) = run(true);
    assert!(with <= 0.35, "with the corridor the tool strayed {with} mm");
    assert!(
        end_depth > 0.8,
        "the second leg's end cut {end_depth} mm deep"
    );
    let c = summary.cutting.as_ref().unwrap();
    assert!(c.gouge_max_mm <= 0.05, "gouge {} mm", c.gouge_max_mm);
    assert!(summary.stable, "{:?}", summary.unstable_reasons);
    let (without, _, _) = run(false);
    eprintln!(
        "guided slot: {with:.3} mm off the path ({without:.3} mm without the corridor), the second leg's end {end_depth:.2} mm deep"
    );
    assert!(without > 1.5, "without the corridor: {without} mm");
}
