//! Damage to recorded IPC byte streams, for the tests that feed a damaged
//! capture to central or to a module: header words set to extreme values,
//! flipped bytes, truncated, repeated, dropped and swapped frames, garbage
//! between frames, early hang-ups, and other events in between.
#![allow(dead_code)]

use proptest::prelude::*;
use std::collections::HashMap;

pub mod central;
pub mod module;

/// Cases per property: `default`, or `DAMAGE_CASES` for a long run
/// (`DAMAGE_CASES=100000 cargo test -p courier-wire --test central_replay`).
pub fn cases(default: u32) -> u32 {
    std::env::var("DAMAGE_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Sets big-endian header word `i` of a frame.
fn set_word(b: &mut [u8], i: usize, v: i32) {
    b[4 * i..4 * i + 4].copy_from_slice(&v.to_be_bytes());
}

#[derive(Debug, Clone)]
pub enum Damage {
    /// Sets header word `word` (0..7) of frame `at` to `value`.
    Word { at: usize, word: usize, value: i32 },
    /// XORs one byte of frame `at` (anywhere, header or body).
    Flip { at: usize, pos: usize, xor: u8 },
    /// Keeps only a prefix of frame `at` (the stream loses sync).
    Truncate { at: usize, keep: usize },
    /// Frame `at` is sent twice (a second Success, Reply, registration…).
    Repeat { at: usize },
    /// Frame `at` is never sent.
    Drop { at: usize },
    /// Frames `at` and `at + 1` change places.
    Swap { at: usize },
    /// Bytes the module writes before frame `at`.
    Garbage { at: usize, bytes: Vec<u8> },
    /// The module of frame `at` disconnects instead of sending it.
    Hangup { at: usize },
    /// Something else happens before frame `at` (for central, the operator
    /// types console command `what`; for a module, its program makes API
    /// call `what`); the test picks it from its list by `what % len`.
    Other { at: usize, what: usize },
}

/// One damage, anywhere in a stream of up to 400 frames.
pub fn damage() -> impl Strategy<Value = Damage> {
    let at = 0usize..400;
    let values = prop_oneof![
        Just(0),
        Just(1),
        Just(-1),
        Just(-4),
        Just(i32::MAX),
        Just(i32::MIN),
        Just(1 << 20),
        -300i32..300,
        any::<i32>(),
    ];
    prop_oneof![
        3 => (at.clone(), 0usize..7, values).prop_map(|(at, word, value)| Damage::Word { at, word, value }),
        3 => (at.clone(), any::<usize>(), 1u8..=255).prop_map(|(at, pos, xor)| Damage::Flip { at, pos, xor }),
        1 => (at.clone(), any::<usize>()).prop_map(|(at, keep)| Damage::Truncate { at, keep }),
        2 => at.clone().prop_map(|at| Damage::Repeat { at }),
        1 => at.clone().prop_map(|at| Damage::Drop { at }),
        1 => at.clone().prop_map(|at| Damage::Swap { at }),
        1 => (at.clone(), prop::collection::vec(any::<u8>(), 1..40)).prop_map(|(at, bytes)| Damage::Garbage { at, bytes }),
        1 => at.clone().prop_map(|at| Damage::Hangup { at }),
        1 => (at, any::<usize>()).prop_map(|(at, what)| Damage::Other { at, what }),
    ]
}

/// One step of the damaged replay.
pub enum Step {
    Bytes(u64, Vec<u8>),
    Hangup(u64),
    Other(usize),
}

/// The steps of `stream` (connection, frame) after `damage`, in order.
pub fn damaged(stream: &[(u64, Vec<u8>)], damage: &[Damage]) -> Vec<Step> {
    let mut frames: Vec<(u64, Vec<u8>)> = stream.to_vec();
    let mut before: HashMap<usize, Vec<Step>> = HashMap::new();
    for d in damage {
        let n = frames.len();
        match d.clone() {
            Damage::Word { at, word, value } => {
                let f = &mut frames[at % n].1;
                if f.len() >= 28 {
                    set_word(f, word, value);
                }
            }
            Damage::Flip { at, pos, xor } => {
                let f = &mut frames[at % n].1;
                if !f.is_empty() {
                    let k = pos % f.len();
                    f[k] ^= xor;
                }
            }
            Damage::Truncate { at, keep } => {
                let f = &mut frames[at % n].1;
                f.truncate(keep % f.len().max(1));
            }
            Damage::Repeat { at } => {
                let f = frames[at % n].clone();
                frames.insert(at % n, f);
            }
            Damage::Drop { at } => {
                frames.remove(at % n);
                if frames.is_empty() {
                    break;
                }
            }
            Damage::Swap { at } => {
                if n > 1 {
                    frames.swap(at % (n - 1), at % (n - 1) + 1);
                }
            }
            Damage::Garbage { at, bytes } => {
                let conn = frames[at % n].0;
                before
                    .entry(at % n)
                    .or_default()
                    .push(Step::Bytes(conn, bytes));
            }
            Damage::Hangup { at } => {
                let conn = frames[at % n].0;
                before.entry(at % n).or_default().push(Step::Hangup(conn));
            }
            Damage::Other { at, what } => {
                before.entry(at % n).or_default().push(Step::Other(what));
            }
        }
    }
    let mut steps = Vec::new();
    for (i, (conn, f)) in frames.into_iter().enumerate() {
        steps.extend(before.remove(&i).unwrap_or_default());
        steps.push(Step::Bytes(conn, f));
    }
    steps
}
