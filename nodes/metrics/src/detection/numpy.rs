//! The two array operations the devkit's detection evaluation leans on, as numpy computes
//! them, so that a curve here is the devkit's value for value: `np.interp` (duplicated
//! abscissae included) and the devkit's NaN-skipping `cummean`.

/// `np.interp(x, xp, fp, left, right)`: `xp` ascending (repeats allowed); `left`/`right` are
/// the values below `xp[0]` and above `xp[last]` (numpy's defaults are `fp[0]` and `fp[last]`).
pub fn interp(x: &[f64], xp: &[f64], fp: &[f64], left: f64, right: f64) -> Vec<f64> {
    let n = xp.len();
    x.iter()
        .map(|&value| {
            if value.is_nan() || n == 0 {
                return f64::NAN;
            }
            if value < xp[0] {
                return left;
            }
            if value > xp[n - 1] {
                return right;
            }
            // The last j with xp[j] <= value, as numpy's binary search finds it.
            let j = xp.partition_point(|&p| p <= value) - 1;
            if j == n - 1 || xp[j] == value {
                return fp[j];
            }
            let slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
            let mut result = slope * (value - xp[j]) + fp[j];
            if result.is_nan() {
                result = slope * (value - xp[j + 1]) + fp[j + 1];
                if result.is_nan() && fp[j] == fp[j + 1] {
                    result = fp[j];
                }
            }
            result
        })
        .collect()
}

/// The devkit's `cummean`: the running mean of the values that are not NaN (0 before the first
/// one); all NaN gives all ones, the worst error.
pub fn cummean(values: &[f64]) -> Vec<f64> {
    if values.iter().all(|v| v.is_nan()) {
        return vec![1.0; values.len()];
    }
    let (mut sum, mut count) = (0.0, 0usize);
    values
        .iter()
        .map(|&v| {
            if !v.is_nan() {
                sum += v;
                count += 1;
            }
            if count == 0 { 0.0 } else { sum / count as f64 }
        })
        .collect()
}

/// `np.linspace(0, 1, n)`.
pub fn unit_linspace(n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![0.0],
        _ => (0..n).map(|i| i as f64 / (n - 1) as f64).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interp_matches_numpy_on_repeats_and_edges() {
        // np.interp([0, 0.25, 0.5, 0.75, 1.0, 1.5], [0.25, 0.5, 0.5, 1.0], [1, 2, 3, 5], right=0)
        // == [1, 1, 3, 4, 5, 0]: a repeated abscissa takes the last value at it.
        let got = interp(
            &[0.0, 0.25, 0.5, 0.75, 1.0, 1.5],
            &[0.25, 0.5, 0.5, 1.0],
            &[1.0, 2.0, 3.0, 5.0],
            1.0,
            0.0,
        );
        assert_eq!(got, vec![1.0, 1.0, 3.0, 4.0, 5.0, 0.0]);
    }

    #[test]
    fn cummean_skips_nan_as_the_devkit_does() {
        assert_eq!(
            cummean(&[f64::NAN, 2.0, 4.0, f64::NAN]),
            vec![0.0, 2.0, 3.0, 3.0]
        );
        assert_eq!(cummean(&[f64::NAN, f64::NAN]), vec![1.0, 1.0]);
        assert_eq!(unit_linspace(5), vec![0.0, 0.25, 0.5, 0.75, 1.0]);
    }
}
