//! Deterministic randomness: a seeded SplitMix64 stream for layout decisions, and stateless
//! hash noise for textures (so a pixel's colour never depends on render order or threads).
//! The generator is the workspace's one (`bevworld_types::SplitMix64`); the draws built on it
//! here are the world's own, and fixed: a seed's bytes depend on them.

use bevworld_types::SplitMix64;
use bevworld_types::splitmix::{GOLDEN_GAMMA, mix};

#[derive(Clone, Debug)]
pub struct Rng {
    stream: SplitMix64,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self {
            stream: SplitMix64::new(seed ^ GOLDEN_GAMMA),
        }
    }

    /// A derived stream, independent of how much the parent has drawn.
    pub fn fork(seed: u64, stream: u64) -> Self {
        Self::new(mix(seed ^ mix(stream.wrapping_add(0xA076_1D64_78BD_642F))))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.stream.next_u64()
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        self.stream.unit()
    }

    pub fn range(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.unit()
    }

    /// An integer in [0, n), by modulo: favours low values by at most n / 2⁶⁴, nothing for the
    /// small `n` a layout draws, and kept because every seed's world was drawn with it.
    pub fn below(&mut self, n: u64) -> u64 {
        if n == 0 { 0 } else { self.next_u64() % n }
    }

    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit().max(1e-300);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Hash of an integer lattice point to [0, 1).
pub fn hash2(x: i64, y: i64, salt: u64) -> f64 {
    let h = mix((x as u64).wrapping_mul(GOLDEN_GAMMA)
        ^ mix((y as u64) ^ salt.wrapping_mul(0xD6E8_FEB8_6659_FD93)));
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1) at frequency 1 (bilinear with smoothstep).
pub fn value_noise(x: f64, y: f64, salt: u64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = hash2(ix, iy, salt);
    let b = hash2(ix + 1, iy, salt);
    let c = hash2(ix, iy + 1, salt);
    let d = hash2(ix + 1, iy + 1, salt);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Two octaves of value noise, for surfaces that should not look tiled.
pub fn fbm(x: f64, y: f64, salt: u64) -> f64 {
    0.65 * value_noise(x, y, salt)
        + 0.35 * value_noise(2.13 * x + 17.0, 2.13 * y - 5.0, salt ^ 0x55)
}

/// A 32-hex-character token, derived deterministically.
pub fn token(seed: u64, kind: &str, index: u64) -> String {
    let mut h = mix(seed ^ 0x1234_5678);
    for byte in kind.bytes() {
        h = mix(h ^ u64::from(byte));
    }
    let a = mix(h ^ index);
    let b = mix(a ^ 0xDEAD_BEEF_CAFE_F00D);
    format!("{a:016x}{b:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_deterministic_and_distinct() {
        let mut a = Rng::new(7);
        let mut b = Rng::new(7);
        let draws: Vec<u64> = (0..4).map(|_| a.next_u64()).collect();
        assert_eq!(draws, (0..4).map(|_| b.next_u64()).collect::<Vec<_>>());
        assert_ne!(Rng::fork(7, 1).next_u64(), Rng::fork(7, 2).next_u64());
        assert_eq!(token(1, "sample", 3), token(1, "sample", 3));
        assert_ne!(token(1, "sample", 3), token(1, "sample", 4));
        assert_eq!(token(1, "x", 0).len(), 32);
    }

    #[test]
    fn noise_is_bounded_and_continuous() {
        for i in 0..1000 {
            let x = i as f64 * 0.137;
            let v = value_noise(x, -x * 0.5, 3);
            assert!((0.0..1.0).contains(&v));
            assert!((value_noise(x + 1e-6, -x * 0.5, 3) - v).abs() < 1e-4);
        }
    }
}
