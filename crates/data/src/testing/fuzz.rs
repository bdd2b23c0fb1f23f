//! A small bounded fuzzer for the readers of untrusted input (the tests' fuzz harnesses):
//! valid inputs mutated at random (bit flips, byte and token replacement, truncation,
//! duplication, digit runs that overflow), each fed to the reader inside `catch_unwind`.
//! Deterministic for a name; `DIFFKFC_FUZZ_CASES` sets the count per reader.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};

use crate::rng::Rng;

/// Cases per reader: `$DIFFKFC_FUZZ_CASES`, else 20 000.
pub fn cases() -> usize {
    std::env::var("DIFFKFC_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000)
}

/// One random mutation of `seed` bytes.
pub fn mutate(seed: &[u8], r: &mut Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + r.below(4) {
        if b.is_empty() {
            b.push(b'0');
        }
        let at = r.below(b.len());
        match r.below(7) {
            0 => b[at] ^= 1 << r.below(8),
            1 => {
                b[at] = [b'0', b'9', b'-', b'.', b'e', b',', b'(', b')', b' ', b'\n', 0, 0xff]
                    [r.below(12)]
            }
            2 => b.truncate(at),
            3 => {
                let end = (at + 1 + r.below(16)).min(b.len());
                let piece = b[at..end].to_vec();
                b.splice(at..at, piece);
            }
            4 => {
                let digits = [
                    "18446744073709551615",
                    "4611686018427387904",
                    "99999999999999999999999",
                    "1e308",
                    "-1",
                    "0",
                    "nan",
                    "inf",
                ][r.below(8)];
                b.splice(at..at, digits.bytes());
            }
            5 => {
                let end = (at + 1 + r.below(8)).min(b.len());
                b.drain(at..end);
            }
            _ => b[at] = r.below(256) as u8,
        }
    }
    b
}

/// Feed `count` mutations of each seed to `read`; returns (ok, clean errors). Panics and slow
/// calls fail the test with the input that caused them.
pub fn fuzz(
    name: &str,
    seeds: &[Vec<u8>],
    count: usize,
    read: &dyn Fn(&[u8]) -> bool,
) -> (usize, usize) {
    let mut r = Rng::new(0xF022 ^ name.len() as u64);
    let (mut ok, mut errors) = (0, 0);
    for k in 0..count {
        let input = mutate(&seeds[k % seeds.len()], &mut r);
        let t0 = Instant::now();
        match catch_unwind(AssertUnwindSafe(|| read(&input))) {
            Ok(true) => ok += 1,
            Ok(false) => errors += 1,
            Err(_) => panic!(
                "{name}: case {k} panicked on input {:?}",
                String::from_utf8_lossy(&input[..input.len().min(400)])
            ),
        }
        assert!(t0.elapsed() < Duration::from_secs(1), "{name}: case {k} took {:?}", t0.elapsed());
    }
    eprintln!(
        "fuzz {name}: {count} cases, {ok} accepted, {errors} clean errors, 0 panics, 0 hangs"
    );
    (ok, errors)
}
