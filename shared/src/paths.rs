//! Where the default configuration files are: relative to the repository the binaries belong
//! to, not to the working directory, so `cd master && cargo run -p h4-master-cli -- loopback`
//! finds `config/sessions/wall-push.toml` like a run from the repository's root does.

use std::path::{Path, PathBuf};

/// The places a default file `rel` (e.g. `config/sessions/wall-push.toml`) is looked for, in
/// order: each directory from the running binary's upwards (a binary in
/// `<repo>/target/release/` finds `<repo>/rel`), the repository these crates were built
/// from, then the working directory.
pub fn candidates(rel: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        let exe = exe.canonicalize().unwrap_or(exe);
        for dir in exe.ancestors().skip(1) {
            out.push(dir.join(rel));
        }
    }
    if let Some(repo) = Path::new(env!("CARGO_MANIFEST_DIR")).parent() {
        out.push(repo.join(rel));
    }
    out.push(PathBuf::from(rel));
    out
}

/// The file a command reads: `explicit` as given (relative to the working directory, as
/// the user typed it), else the default `rel` found by [`candidates`]. The error says where
/// it looked and how to name a file instead (`flag`).
pub fn default_config(explicit: Option<&Path>, rel: &str, flag: &str) -> Result<PathBuf, String> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    let tried = candidates(rel);
    if let Some(found) = tried.iter().find(|p| p.is_file()) {
        return Ok(found.clone());
    }
    let mut dirs: Vec<String> = Vec::new();
    for p in &tried {
        let d = p.display().to_string();
        if !dirs.contains(&d) {
            dirs.push(d);
        }
    }
    Err(format!(
        "the default {rel} was not found next to the binary, in the repository it was built \
         from, or in the working directory (looked for {}); name a file with {flag} FILE",
        dirs.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_found_from_anywhere_and_explicit_paths_are_kept() {
        let found = default_config(None, "config/sessions/wall-push.toml", "--config").unwrap();
        assert!(found.is_file(), "{}", found.display());
        assert!(found.is_absolute(), "{}", found.display());
        let p = Path::new("some/where.toml");
        assert_eq!(default_config(Some(p), "x", "--config").unwrap(), p);
        let err = default_config(None, "config/no-such-file.toml", "--config").unwrap_err();
        assert!(
            err.contains("no-such-file") && err.contains("--config FILE"),
            "{err}"
        );
    }
}
