//! Deterministic mutation fuzzing of every reader: random byte changes, insertions and
//! truncations of the committed excerpts must give `Ok` or a `Format` error naming the
//! file — never a panic, and never an allocation beyond the input's size (a panic or an
//! abort would fail the test).

use std::path::Path;

use panoman_mocap::MocapError;
use panoman_mocap::{bvh, c3d, csm, vsk};

/// xorshift64*: a fixed, dependency-free pseudo-random sequence.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn data(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name),
    )
    .unwrap()
}

/// `n` mutants of `bytes`; in `hot`, the first bytes get most of the edits (headers).
fn mutants(bytes: &[u8], n: usize, hot: usize, seed: u64) -> Vec<Vec<u8>> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let mut b = bytes.to_vec();
            for _ in 0..1 + rng.below(4) {
                let region = if rng.below(4) < 3 {
                    hot.min(b.len())
                } else {
                    b.len()
                };
                let at = rng.below(region);
                match rng.below(5) {
                    0 | 1 => {
                        if let Some(x) = b.get_mut(at) {
                            *x = rng.next() as u8;
                        }
                    }
                    2 => b.insert(at.min(b.len()), rng.next() as u8),
                    3 => {
                        if at < b.len() {
                            b.remove(at);
                        }
                    }
                    _ => b.truncate(at),
                }
            }
            b
        })
        .collect()
}

/// Asserts an error is a format error naming `name`; returns whether it was an error.
fn check<T>(r: Result<T, MocapError>, name: &str) -> bool {
    if let Err(e) = &r {
        assert!(matches!(e, MocapError::Format { .. }), "{e:?}");
        assert!(e.to_string().starts_with(name), "{e}");
    }
    r.is_err()
}

#[test]
fn c3d_mutants() {
    let b = data("nick_freeform_001_head.c3d");
    let mut errors = 0;
    for m in mutants(&b, 3000, 4608, 1) {
        errors += usize::from(check(c3d::parse_c3d(&m, Path::new("m.c3d")), "m.c3d"));
    }
    // Both outcomes occur (edits in unused header bytes are harmless).
    assert!((300..2900).contains(&errors), "{errors} errors of 3000");
}

#[test]
fn text_mutants() {
    let cases: [(&str, &str, usize); 3] = [
        ("ThomasFechten_head.csm", "m.csm", 2000),
        ("01_01_head.bvh", "m.bvh", 5200),
        ("Nick01.vsk", "m.vsk", 38000),
    ];
    for (k, (file, name, hot)) in cases.into_iter().enumerate() {
        let b = data(file);
        let mut errors = 0;
        for m in mutants(&b, 600, hot, 7 + k as u64) {
            let Ok(text) = String::from_utf8(m) else {
                continue;
            };
            let p = Path::new(name);
            errors += usize::from(match k {
                0 => check(csm::parse_csm(&text, p), name),
                1 => check(bvh::parse_bvh(&text, p), name),
                _ => check(vsk::parse_vsk(&text, p), name),
            });
        }
        assert!(
            errors >= 60,
            "{file}: only {errors} of 600 mutants rejected"
        );
    }
}
