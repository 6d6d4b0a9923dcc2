//! A short fingerprint of a file's bytes (FNV-1a, 64 bit, hex). Products carry it so that
//! they say what made them: exported features name their weights, world-model weights name
//! their tokenizer, a checkpoint names each of its files. It detects accidents (a file from
//! another run, flipped bytes), not an adversary.

use std::path::Path;

/// The digest of `bytes`.
pub fn bytes_digest(bytes: &[u8]) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &byte in bytes {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{hash:016x}")
}

/// The digest of the file at `path`.
pub fn file_digest(path: &Path) -> std::io::Result<String> {
    Ok(bytes_digest(&std::fs::read(path)?))
}
