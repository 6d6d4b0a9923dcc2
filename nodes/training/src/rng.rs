//! A small deterministic generator (SplitMix64) whose whole state is one `u64`, so that a
//! checkpoint stores it and a resumed run draws the same frames and rays.

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplitMix64 {
    pub state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
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
