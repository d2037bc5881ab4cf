//! Cutting in the real processes: `h4-master loopback --config config/sessions/cut-pocket.toml
//! --out DIR` runs the slave's 1 kHz loop over a cutting world (the session's `[cutting]`,
//! `[fixtures]` and controller keys passed on in its world file) and the operator's script on
//! the master, over iceoryx2. The slave removes material (its summary's
//! `removed_volume_mm3`), the true force stays within the slave's limit, nothing goes below
//! the depth floor, and at the end the slave writes the part: a PNG height map and a closed
//! binary STL whose enclosed volume is the block's less what was removed. Nothing asserts a
//! wall-clock duration.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_tests::procs::*;

/// The volume a binary STL encloses (divergence theorem over its triangles), mm³.
fn stl_volume_mm3(stl: &[u8]) -> f64 {
    let n = u32::from_le_bytes([stl[80], stl[81], stl[82], stl[83]]) as usize;
    assert_eq!(stl.len(), 84 + 50 * n, "a binary STL of {n} triangles");
    let f = |o: usize| {
        f64::from(f32::from_le_bytes([
            stl[o],
            stl[o + 1],
            stl[o + 2],
            stl[o + 3],
        ]))
    };
    let mut v = 0.0;
    for t in 0..n {
        let b = 84 + 50 * t + 12;
        let p = |k: usize| [f(b + 12 * k), f(b + 12 * k + 4), f(b + 12 * k + 8)];
        let (a, b, c) = (p(0), p(1), p(2));
        v += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))
            / 6.0;
    }
    v.abs()
}

#[test]
fn loopback_cuts_the_pocket_and_the_slave_writes_the_part() {
    let _g = serial();
    let scratch = Scratch::new("process-cutting-part");
    let out = scratch.path("part");
    let mut args = s(&[
        "--config",
        "config/sessions/cut-pocket.toml",
        "--duration-s",
        "6",
    ]);
    args.push("--out".into());
    args.push(out.display().to_string());
    let (v, log) = loopback_summary("process-cutting", &args, 90.0);
    let removed = f(&v["slave"], "removed_volume_mm3");
    assert!(removed > 50.0, "removed {removed} mm³\n{v:#}\n{log}");
    assert!(
        f(&v, "max_force_n") <= f(&v["slave"], "force_limit_n"),
        "{v:#}"
    );
    assert_eq!(v["stable"], true, "{v:#}");
    let png = std::fs::read(out.join("height.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let stl = std::fs::read(out.join("part.stl")).unwrap();
    // The block: 150 × 150 × 30 mm of 0.25 mm cells; the STL's surface runs through the
    // cells' centres (149.75 mm square); the part is that less the removed volume, within
    // 1 % of the removed volume.
    let block = 149.75 * 149.75 * 30.0;
    let vol = stl_volume_mm3(&stl);
    assert!(
        (vol - (block - removed)).abs() < 0.01 * removed.max(100.0),
        "STL encloses {vol} mm³, block less removed {}",
        block - removed
    );
}
