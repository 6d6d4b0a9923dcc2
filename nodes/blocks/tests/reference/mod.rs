//! f64 references and input sweeps shared by the fast-math and activation tests.

#![allow(dead_code)]

/// Points over [-12, 12], denser near 0 where GELU bends.
pub fn sweep() -> Vec<f32> {
    (-60_000..=60_000)
        .map(|i| {
            let t = i as f32 / 5_000.0;
            t * t.abs()
        })
        .filter(|x| x.abs() <= 12.0)
        .collect()
}

/// erf in f64 by its Taylor series for |x| < 3 and the asymptotic continued fraction
/// beyond, each far more accurate than the f32 error being checked.
pub fn erf_f64(x: f64) -> f64 {
    let a = x.abs();
    let value = if a < 3.0 {
        // erf(x) = 2/√π Σ (-1)^n x^(2n+1) / (n! (2n+1))
        let mut sum = 0.0;
        let mut term = a;
        let mut n = 0.0;
        while term.abs() > 1e-18 || n < 5.0 {
            sum += term / (2.0 * n + 1.0);
            n += 1.0;
            term *= -a * a / n;
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    } else {
        // erfc(x) = e^{-x²}/√π · 1/(x + 1/2/(x + 1/(x + 3/2/(x + ...))))
        let mut fraction = a;
        for k in (1..60).rev() {
            fraction = a + f64::from(k) / 2.0 / fraction;
        }
        1.0 - (-a * a).exp() / std::f64::consts::PI.sqrt() / fraction
    };
    value.copysign(x)
}
