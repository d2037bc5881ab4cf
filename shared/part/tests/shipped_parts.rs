//! The shipped parts: regenerating them gives the committed bytes, and each loads (closed,
//! manifold, outward) with the volume its shape has, and fits the shipped stock.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_part::shapes;
use h4_part::{LoadOptions, Part, Placement, StockBox};

fn parts_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/parts")
}

#[test]
fn regenerating_the_shipped_parts_gives_the_committed_bytes() {
    for (name, mesh) in [
        ("dome-block.stl", shapes::shipped_dome_block()),
        ("pawn.stl", shapes::shipped_pawn()),
    ] {
        let committed = std::fs::read(parts_dir().join(name)).expect("committed part");
        let made = mesh.to_binary_stl().expect("stl bytes");
        assert_eq!(made.len(), committed.len(), "{name}: size");
        assert!(
            made == committed,
            "{name}: bytes differ from the generator's"
        );
    }
    // Control: a different resolution gives different bytes.
    let other = shapes::dome_block(2.0).to_binary_stl().expect("stl bytes");
    let committed = std::fs::read(parts_dir().join("dome-block.stl")).expect("committed part");
    assert!(other != committed);
}

/// The shipped stock (config/sessions/cut-*.toml): 150 × 150 × 30 mm, top at z = −250.
fn stock() -> StockBox {
    StockBox {
        centre_top_mm: [-25.0, 0.0, -250.0],
        size_mm: [150.0, 150.0],
        thickness_mm: 30.0,
    }
}

fn placed_on_the_bottom() -> Placement {
    Placement {
        translation_mm: [-25.0, 0.0, -280.0],
        rotation_deg: [0.0, 0.0, 0.0],
    }
}

#[test]
fn the_dome_block_loads_with_its_volume_and_fits_the_stock() {
    let part = Part::load(
        &parts_dir().join("dome-block.stl"),
        placed_on_the_bottom(),
        Some(&stock()),
        &LoadOptions::default(),
    )
    .expect("the dome block loads");
    // Volume by the height function on a fine midpoint grid (the mesh interpolates it
    // linearly over 1 mm cells: a few mm³ of a 96 000 mm³ part).
    let n = 800;
    let (sx, sy) = (80.0, 60.0);
    let mut v = 0.0;
    for i in 0..n {
        for j in 0..n {
            let x = -40.0 + sx * (i as f64 + 0.5) / n as f64;
            let y = -30.0 + sy * (j as f64 + 0.5) / n as f64;
            v += shapes::dome_block_height_mm(x, y) * sx * sy / (n * n) as f64;
        }
    }
    assert!(
        (part.volume_mm3 - v).abs() < 0.005 * v,
        "mesh {} mm³, shape {v} mm³",
        part.volume_mm3
    );
    // The dome's top is inside just below and outside just above.
    assert!(part.contains([-25.0 + 15.0, 0.0, -280.0 + 23.5]));
    assert!(!part.contains([-25.0 + 15.0, 0.0, -280.0 + 24.5]));
}

#[test]
fn the_pawn_loads_with_its_volume_and_fits_the_stock() {
    let part = Part::load(
        &parts_dir().join("pawn.stl"),
        placed_on_the_bottom(),
        Some(&stock()),
        &LoadOptions::default(),
    )
    .expect("the pawn loads");
    // Volume of the turned profile (Pappus on each frustum: π h (r0² + r0 r1 + r1²) / 3),
    // the mesh's polygon of 96 sides holding sin(2π/96)·96/2π of the circle's area.
    let p = shapes::pawn_profile_mm();
    let frusta: f64 = p
        .windows(2)
        .map(|w| {
            let ([r0, z0], [r1, z1]) = (w[0], w[1]);
            std::f64::consts::PI * (z1 - z0) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0
        })
        .sum();
    let polygon = (2.0 * std::f64::consts::PI / 96.0).sin() * 96.0 / (2.0 * std::f64::consts::PI);
    let expected = frusta * polygon;
    assert!(
        (part.volume_mm3 - expected).abs() < 1e-3 * expected,
        "mesh {} mm³, profile {expected} mm³",
        part.volume_mm3
    );
    // Control: lifted 10 mm its head (22 mm above its base) leaves the stock's top.
    let lifted = Placement {
        translation_mm: [-25.0, 0.0, -270.0],
        ..placed_on_the_bottom()
    };
    let err = Part::load(
        &parts_dir().join("pawn.stl"),
        lifted,
        Some(&stock()),
        &LoadOptions::default(),
    )
    .expect_err("a part above the stock's top");
    assert!(err.to_string().contains("does not fit the stock"), "{err}");
}
