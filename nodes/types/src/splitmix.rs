//! SplitMix64 (Steele, Lea and Flood 2014), the one seeded generator of the workspace: the
//! trainings' frame and ray draws, the synthetic world's layout, and host-drawn test tensors.
//! Its whole state is one `u64`, so that a checkpoint stores it and a resumed run draws the
//! same frames and rays; nothing touches a process-wide generator.

/// The golden-ratio increment of the state, also a good constant to decorrelate seeds.
pub const GOLDEN_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// SplitMix64's finaliser: a strong 64-bit mix, also the stateless hash of the synthetic
/// world's textures and tokens.
pub fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplitMix64 {
    pub state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN_GAMMA);
        mix(self.state)
    }

    /// Uniform in `0..n` (n ≥ 1), by rejection so that no value is favoured.
    pub fn below(&mut self, n: usize) -> usize {
        let n = n.max(1) as u64;
        let zone = u64::MAX - u64::MAX % n;
        loop {
            let v = self.next_u64();
            if v < zone {
                return (v % n) as usize;
            }
        }
    }

    /// Uniform in [0, 1), from the top 53 bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// `count` distinct indices of `0..weights.len()`, drawn one after another with
    /// probability proportional to each remaining index's weight (Efraimidis and Spirakis:
    /// the `count` largest keys `ln(u) / w`). Indices of weight 0 come last, and only when the
    /// others run out; `count ≥ n` gives them all. Returned in draw order (largest key first).
    pub fn choose_weighted(&mut self, weights: &[f32], count: usize) -> Vec<usize> {
        let mut keyed: Vec<(f64, usize)> = weights
            .iter()
            .enumerate()
            .map(|(i, &w)| {
                // 1 - unit() is in (0, 1], so the logarithm is finite.
                let log_u = (1.0 - self.unit()).ln();
                let key = if w > 0.0 {
                    log_u / f64::from(w)
                } else {
                    f64::NEG_INFINITY
                };
                (key, i)
            })
            .collect();
        let count = count.min(keyed.len());
        let by_key = |a: &(f64, usize), b: &(f64, usize)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        if count < keyed.len() && count > 0 {
            keyed.select_nth_unstable_by(count - 1, by_key);
        }
        keyed.truncate(count);
        keyed.sort_by(by_key);
        keyed.into_iter().map(|(_, i)| i).collect()
    }

    /// `count` distinct indices of `0..n` (all of them, shuffled, when count ≥ n), by a partial
    /// Fisher–Yates shuffle.
    pub fn choose(&mut self, n: usize, count: usize) -> Vec<usize> {
        let mut pool: Vec<usize> = (0..n).collect();
        let count = count.min(n);
        for i in 0..count {
            let j = i + self.below(n - i);
            pool.swap(i, j);
        }
        pool.truncate(count);
        pool
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_reference_stream() {
        // Vigna's splitmix64.c seeded with 1234567.
        let mut rng = SplitMix64::new(1_234_567);
        let draws: Vec<u64> = (0..5).map(|_| rng.next_u64()).collect();
        assert_eq!(
            draws,
            [
                6_457_827_717_110_365_317,
                3_203_168_211_198_807_973,
                9_817_491_932_198_370_423,
                4_593_380_528_125_082_431,
                16_408_922_859_458_223_821,
            ]
        );
    }

    #[test]
    fn draws_are_distinct_and_reproducible() {
        let mut a = SplitMix64::new(5);
        let picks = a.choose(10, 4);
        let mut sorted = picks.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 4);
        assert!(picks.iter().all(|&i| i < 10));
        assert_eq!(SplitMix64::new(5).choose(10, 4), picks);
        assert_eq!(a.choose(3, 10).len(), 3);
    }

    #[test]
    fn weighted_draws_follow_the_weights_and_are_distinct() {
        // One index of three with weights 1 : 3 : 0, many times: about 1/4 and 3/4, never the third.
        let mut rng = SplitMix64::new(11);
        let mut counts = [0usize; 3];
        for _ in 0..8000 {
            counts[rng.choose_weighted(&[1.0, 3.0, 0.0], 1)[0]] += 1;
        }
        assert_eq!(counts[2], 0);
        let share = counts[1] as f64 / 8000.0;
        assert!(
            (share - 0.75).abs() < 0.02,
            "share of the weight-3 index: {share}"
        );
        // Several at once are distinct; asking for all gives all, the weight-0 index last.
        let weights: Vec<f32> = (0..50).map(|i| (i % 7) as f32).collect();
        let picks = SplitMix64::new(3).choose_weighted(&weights, 20);
        let mut sorted = picks.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 20);
        assert!(picks.iter().all(|&i| weights[i] > 0.0));
        assert_eq!(SplitMix64::new(3).choose_weighted(&weights, 20), picks);
        let all = SplitMix64::new(3).choose_weighted(&[2.0, 0.0, 1.0], 10);
        assert_eq!(all.len(), 3);
        assert_eq!(all[2], 1);
    }
}
