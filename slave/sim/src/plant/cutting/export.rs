//! The part that comes out: the machined height field as a PNG height map and a binary STL
//! (a closed solid a CAD tool or slicer opens), and a deviation map (PNG) against a target.

use std::io::Write;
use std::path::Path;

use plotters::prelude::*;

use super::Stock;

/// Why a file could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ExportError {
    /// The file.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

fn err(path: &Path, e: &dyn std::fmt::Display) -> ExportError {
    ExportError {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// A colour for `t` in 0..1 along a perceptually ordered ramp (dark blue → yellow).
fn ramp(t: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 5] = [
        (0.07, 0.05, 0.35),
        (0.23, 0.32, 0.55),
        (0.13, 0.57, 0.55),
        (0.37, 0.79, 0.38),
        (0.99, 0.91, 0.14),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let c = |a: f64, b: f64| ((a + (b - a) * f) * 255.0).round() as u8;
    RGBColor(
        c(STOPS[i].0, STOPS[i + 1].0),
        c(STOPS[i].1, STOPS[i + 1].1),
        c(STOPS[i].2, STOPS[i + 1].2),
    )
}

/// A diverging colour for `t` in −1..1: blue (below), white (0), red (above).
fn diverging(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let w = |v: f64| (255.0 * (1.0 - v)).round() as u8;
    if t < 0.0 {
        RGBColor(w(-t), w(-0.6 * t), 255)
    } else {
        RGBColor(255, w(0.6 * t), w(t))
    }
}

/// Writes one pixel per cell, +y up, coloured by `color(ix, iy)`.
fn write_png(
    path: &Path,
    stock: &Stock,
    color: impl Fn(usize, usize) -> RGBColor,
) -> Result<(), ExportError> {
    let (nx, ny) = stock.dims();
    let root = BitMapBackend::new(path, (nx as u32, ny as u32)).into_drawing_area();
    for iy in 0..ny {
        for ix in 0..nx {
            root.draw_pixel((ix as i32, (ny - 1 - iy) as i32), &color(ix, iy))
                .map_err(|e| err(path, &e))?;
        }
    }
    root.present().map_err(|e| err(path, &e))
}

/// The height map: the uncut top yellow, the deepest cut (or the block's bottom, whichever
/// is higher, at most 10 mm below the top) dark blue; one pixel per cell, +x right, +y up.
pub fn write_height_png(path: &Path, stock: &Stock) -> Result<(), ExportError> {
    let top = stock.top_mm();
    let lowest = stock
        .heights_mm()
        .iter()
        .fold(top, |m, h| m.min(f64::from(*h)));
    let span = (top - lowest).clamp(0.1, 10.0);
    write_png(path, stock, |ix, iy| {
        ramp(1.0 - (top - stock.height_at(ix, iy)) / span)
    })
}

/// The deviation map against `target(x_mm, y_mm)` (the target height, mm): red where
/// material is left above the target, blue where the cut went below it, white within
/// ±`full_scale_mm` / 50; saturated at ±`full_scale_mm`.
pub fn write_deviation_png(
    path: &Path,
    stock: &Stock,
    full_scale_mm: f64,
    target: impl Fn(f64, f64) -> f64,
) -> Result<(), ExportError> {
    write_png(path, stock, |ix, iy| {
        let c = stock.cell_centre_mm(ix, iy);
        diverging((stock.height_at(ix, iy) - target(c[0], c[1])) / full_scale_mm)
    })
}

/// Writes the machined block as a closed binary STL in mm: the height field's top (two
/// triangles between each four neighbouring cell centres), four walls and the bottom.
pub fn write_stl(path: &Path, stock: &Stock) -> Result<(), ExportError> {
    let (nx, ny) = stock.dims();
    let file = std::fs::File::create(path).map_err(|e| err(path, &e))?;
    let mut w = std::io::BufWriter::new(file);
    let p = |ix: usize, iy: usize| -> [f32; 3] {
        let c = stock.cell_centre_mm(ix, iy);
        [c[0] as f32, c[1] as f32, stock.height_at(ix, iy) as f32]
    };
    let bottom = stock.bottom_mm() as f32;
    let low = |v: [f32; 3]| [v[0], v[1], bottom];
    let mut tris: Vec<[[f32; 3]; 3]> = Vec::with_capacity(2 * nx * ny + 4 * (nx + ny) + 2);
    for iy in 0..ny.saturating_sub(1) {
        for ix in 0..nx.saturating_sub(1) {
            let (a, b, c, d) = (p(ix, iy), p(ix + 1, iy), p(ix + 1, iy + 1), p(ix, iy + 1));
            tris.push([a, b, c]);
            tris.push([a, c, d]);
        }
    }
    // The boundary, counter-clockwise seen from above: each edge makes a wall quad.
    let mut ring: Vec<[f32; 3]> = Vec::with_capacity(2 * (nx + ny));
    ring.extend((0..nx).map(|ix| p(ix, 0)));
    ring.extend((1..ny).map(|iy| p(nx - 1, iy)));
    ring.extend((0..nx.saturating_sub(1)).rev().map(|ix| p(ix, ny - 1)));
    ring.extend((1..ny.saturating_sub(1)).rev().map(|iy| p(0, iy)));
    for i in 0..ring.len() {
        let (a, b) = (ring[i], ring[(i + 1) % ring.len()]);
        tris.push([a, low(a), low(b)]);
        tris.push([a, low(b), b]);
    }
    let (c0, c1, c2, c3) = (
        low(p(0, 0)),
        low(p(nx - 1, 0)),
        low(p(nx - 1, ny - 1)),
        low(p(0, ny - 1)),
    );
    tris.push([c0, c2, c1]);
    tris.push([c0, c3, c2]);
    let mut header = [0u8; 80];
    let text = b"h4-teleop machined stock, mm";
    header[..text.len()].copy_from_slice(text);
    let io = |e: std::io::Error| err(path, &e);
    w.write_all(&header).map_err(io)?;
    w.write_all(&(tris.len() as u32).to_le_bytes())
        .map_err(io)?;
    for t in &tris {
        let n = normal(t);
        for v in std::iter::once(&n).chain(t.iter()) {
            for c in v {
                w.write_all(&c.to_le_bytes()).map_err(io)?;
            }
        }
        w.write_all(&[0u8; 2]).map_err(io)?;
    }
    w.flush().map_err(io)
}

/// The unit normal of a triangle (right-hand rule), zero if degenerate.
fn normal(t: &[[f32; 3]; 3]) -> [f32; 3] {
    let u = [t[1][0] - t[0][0], t[1][1] - t[0][1], t[1][2] - t[0][2]];
    let v = [t[2][0] - t[0][0], t[2][1] - t[0][1], t[2][2] - t[0][2]];
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 0.0 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Tool, ToolKind};
    use super::*;

    /// The STL is a closed solid: its size matches its triangle count, and its enclosed
    /// volume (divergence theorem) is the block's minus what was cut, to rounding of the
    /// cell-centre surface.
    #[test]
    fn stl_is_a_closed_solid_of_the_machined_volume() {
        let mut s = Stock::new([0.0, 0.0, 0.0], [20.0, 16.0], 5.0, 0.25).unwrap();
        let t = Tool {
            kind: ToolKind::Flat,
            radius_mm: 2.0,
            ..Tool::default()
        };
        s.sweep(&t, [-3.0, 0.0, -1.0], [3.0, 0.0, -1.0]);
        let dir = std::env::temp_dir().join(format!("h4-stl-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("part.stl");
        write_stl(&path, &s).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let n = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as usize;
        assert_eq!(bytes.len(), 84 + 50 * n);
        let mut vol = 0.0f64;
        for k in 0..n {
            let off = 84 + 50 * k + 12;
            let v: Vec<f64> = (0..9)
                .map(|i| {
                    let b = &bytes[off + 4 * i..off + 4 * i + 4];
                    f64::from(f32::from_le_bytes(b.try_into().unwrap()))
                })
                .collect();
            let (a, b, c) = (&v[0..3], &v[3..6], &v[6..9]);
            vol += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0;
        }
        // The surface through the cell centres spans (n − 1) cells each way.
        let (nx, ny) = s.dims();
        let full = (nx - 1) as f64 * 0.25 * (ny - 1) as f64 * 0.25 * 5.0;
        let cut = s.removed_mm3();
        assert!(
            (vol - (full - cut)).abs() < 0.1 * cut,
            "volume {vol} vs {}",
            full - cut
        );
        write_height_png(&dir.join("h.png"), &s).unwrap();
        write_deviation_png(&dir.join("d.png"), &s, 0.5, |_, _| 0.0).unwrap();
        assert!(std::fs::metadata(dir.join("h.png")).unwrap().len() > 100);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
