//! The fuzz targets of `fuzz/` (decoder, gate, byte-level receive path, arm and experiment
//! configuration parsers, `h4-slave kin`'s input) run in CI without the coverage-guided
//! engine: each target gets its kept corpus (`fuzz/corpus/<target>/`, grown by the long
//! `fuzz/run.sh` runs) and then mutations of it (bit flips, byte changes, insertions,
//! deletions, splices, random bytes; fixed seed) up to 10⁵ inputs, and must neither panic
//! nor break its invariants (checked inside each target). The session configuration parser
//! (in `h4-master`, which the fuzz crate does not build) is fuzzed here the same way.

#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../fuzz/src/targets.rs"]
mod targets;

use std::path::PathBuf;

const INPUTS_PER_TARGET: usize = 100_000;

fn corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target);
    let mut out: Vec<Vec<u8>> = std::fs::read_dir(&dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| std::fs::read(e.path()).ok())
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const INTERESTING: [u8; 12] = [
    0, 1, 0x7F, 0x80, 0xFF, b'=', b'[', b'"', b'.', b'\n', b'H', b'4',
];

fn mutate(seed: &[u8], other: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(8) {
        match rng.below(7) {
            0 if !b.is_empty() => {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
            1 if !b.is_empty() => {
                let i = rng.below(b.len());
                b[i] = INTERESTING[rng.below(INTERESTING.len())];
            }
            2 => {
                let i = rng.below(b.len() + 1);
                b.insert(i, rng.next() as u8);
            }
            3 if !b.is_empty() => {
                let i = rng.below(b.len());
                let n = rng.below(b.len() - i + 1).min(16);
                b.drain(i..i + n);
            }
            4 if !other.is_empty() => {
                let i = rng.below(b.len() + 1);
                let j = rng.below(other.len());
                let n = rng.below(other.len() - j + 1).min(64);
                b.splice(i..i, other[j..j + n].iter().copied());
            }
            5 => b.truncate(rng.below(b.len() + 1)),
            _ => {
                let n = rng.below(300);
                b = (0..n).map(|_| rng.next() as u8).collect();
            }
        }
    }
    b
}

fn run(target: &str, seeds: &[Vec<u8>], f: impl Fn(&[u8])) {
    assert!(!seeds.is_empty(), "{target}: empty corpus");
    let mut rng = Rng(0x2545_F491_4F6C_DD1D ^ target.len() as u64);
    for s in seeds {
        f(s);
    }
    for _ in seeds.len()..INPUTS_PER_TARGET {
        let a = &seeds[rng.below(seeds.len())];
        let b = &seeds[rng.below(seeds.len())];
        f(&mutate(a, b, &mut rng));
    }
}

#[test]
fn every_fuzz_target_survives_its_corpus_and_1e5_mutations() {
    for (name, f) in targets::TARGETS {
        run(name, &corpus(name), f);
    }
}

#[test]
fn the_session_config_parser_survives_1e5_mutations() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions");
    let seeds: Vec<Vec<u8>> = ["wall-push.toml", "cutting-guided.toml"]
        .iter()
        .map(|f| std::fs::read(root.join(f)).unwrap())
        .collect();
    run("session_config", &seeds, |d| {
        let text = String::from_utf8_lossy(d);
        let _ =
            h4_shared::config::parse::<h4_master_sim::session::SessionConfig>(&text, "fuzz", &[]);
    });
}
