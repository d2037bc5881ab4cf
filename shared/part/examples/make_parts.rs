//! Writes the shipped parts (`config/parts/dome-block.stl`, `config/parts/pawn.stl`) as
//! binary STL from their generators in `h4_part::shapes`; no downloaded data.
//!
//!   cargo run -p h4-part --example make_parts [-- OUT_DIR]   (default: config/parts)
//!
//! `shared/part/tests/shipped_parts.rs` checks that the committed files are these bytes.

use std::path::PathBuf;

fn main() -> std::io::Result<()> {
    let dir = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/parts"));
    std::fs::create_dir_all(&dir)?;
    for (name, mesh) in [
        ("dome-block.stl", h4_part::shapes::shipped_dome_block()),
        ("pawn.stl", h4_part::shapes::shipped_pawn()),
    ] {
        let bytes = mesh.to_binary_stl()?;
        let path = dir.join(name);
        std::fs::write(&path, &bytes)?;
        println!(
            "{}: {} triangles, {} bytes",
            path.display(),
            mesh.faces.len(),
            bytes.len()
        );
    }
    Ok(())
}
