//! Scalar f32 math written to vectorise: no branches the compiler cannot turn into selects, no
//! libm calls (on x86-64 without SSE4.1 even `floor` and `round` are calls). Host kernels
//! (`activation`, the tokenizer's renderer) run these over slices, in parallel over chunks.
//! Each is within a few ulp of libm; `tests/fast_math.rs` holds the bounds.

/// `erf` for f32 within a few ulp, branch-free: two minimax polynomials (coefficients as
/// published by Norbert Juffa for `erff`; each within 3e-8 of erf in exact arithmetic, checked
/// in `tests/activation.rs`), both evaluated and one selected, so that the loop vectorises.
/// - `|x| < 0.927734375`: `erf(x) = x + x · P(x²)`;
/// - `0.927734375 ≤ |x| < 4`: `erf(|x|) = 1 − e^{−(a + a · Q(a))}`, `a = |x|`;
/// - `|x| ≥ 4`: `±1` (erf(4) differs from 1 by 1.5e-8, below half an f32 ulp).
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    const P: [f32; 6] = [
        1.283_791_7e-1,
        -3.761_253_4e-1,
        1.128_199_3e-1,
        -2.676_813_5e-2,
        4.991_194_2e-3,
        -5.967_617e-4,
    ];
    const Q: [f32; 7] = [
        1.287_175_1e-1,
        6.348_467e-1,
        1.067_778_8e-1,
        -2.425_462_2e-2,
        3.883_964_4e-3,
        -3.831_971_3e-4,
        1.728_534_7e-5,
    ];
    let a = x.abs();
    let x2 = x * x;
    let near = {
        let p = ((((P[5] * x2 + P[4]) * x2 + P[3]) * x2 + P[2]) * x2 + P[1]) * x2 + P[0];
        x + x * p
    };
    let far = {
        let b = a.min(4.0);
        let q = (((((Q[6] * b + Q[5]) * b + Q[4]) * b + Q[3]) * b + Q[2]) * b + Q[1]) * b + Q[0];
        (1.0 - exp(-(b + b * q))).copysign(x)
    };
    let value = if a < 0.927_734_4 { near } else { far };
    let value = if a >= 4.0 { 1.0f32.copysign(x) } else { value };
    // `min` above drops NaN; give it back.
    if x.is_nan() { x } else { value }
}

/// `e^x` for f32, within ~2 ulp on `[−87, 88]`: `x = n·ln 2 + r` with `|r| ≤ ½ ln 2`,
/// `e^x = 2ⁿ · e^r`, `e^r` by Cephes' polynomial. Below −87 (where e^x leaves the normal
/// range) it is 0, above 88 it is +∞ (f32 overflows at 88.72), NaN stays NaN. Rounding uses
/// the 1.5·2²³ trick rather than `round()`, which needs SSE4.1 to vectorise.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2²³
    let clamped = x.clamp(-87.0, 88.0);
    // `clamp` keeps NaN, and NaN must not reach the integer conversion below as garbage.
    let x = if clamped.is_nan() { 0.0 } else { clamped };
    let shifted = x * LOG2_E + ROUND;
    let n = shifted - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e_r = p * r * r + r + 1.0;
    // 2ⁿ from the bits of `shifted`, whose mantissa holds n + 2²² as an integer (its ulp is 1):
    // `n as i32` is a saturating conversion, and its clamping to i32's range kept the whole
    // function four times slower on AVX-512 than this integer subtraction, which gives the same
    // n for every |n| < 2²² (here |n| ≤ 127).
    let n_biased = shifted
        .to_bits()
        .wrapping_sub(ROUND.to_bits())
        .wrapping_add(127);
    let scale = f32::from_bits(n_biased << 23);
    let value = e_r * scale;
    let value = if clamped <= -87.0 { 0.0 } else { value };
    let value = if clamped >= 88.0 {
        f32::INFINITY
    } else {
        value
    };
    if clamped.is_nan() { clamped } else { value }
}

/// `ln(1 + y)` for `y ≥ 0` (the range `log_sigmoid` needs), within a few ulp: `u = 1 + y`,
/// `ln u` by Cephes' `logf` (`u = m · 2ᵉ`, a polynomial in `m − 1`), then Goldberg's
/// correction `ln(u) · y / (u − 1)`, which restores the bits of `y` lost in `1 + y`.
#[inline(always)]
pub fn log1p(y: f32) -> f32 {
    const SQRT_HALF: f32 = std::f32::consts::FRAC_1_SQRT_2;
    let u = 1.0 + y;
    let bits = u.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 126;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000); // [0.5, 1)
    let small = m < SQRT_HALF;
    e = if small { e - 1 } else { e };
    m = if small { m + m - 1.0 } else { m - 1.0 };
    let z = m * m;
    let mut p = 7.037_683_6e-2f32;
    p = p * m - 1.151_461e-1;
    p = p * m + 1.167_699_9e-1;
    p = p * m - 1.242_014_1e-1;
    p = p * m + 1.424_932_3e-1;
    p = p * m - 1.666_805_8e-1;
    p = p * m + 2.000_071_5e-1;
    p = p * m - 2.499_999_4e-1;
    p = p * m + 3.333_333e-1;
    let e = e as f32;
    let mut ln_u = p * m * z;
    ln_u += -2.121_944_4e-4 * e;
    ln_u += -0.5 * z;
    ln_u += m;
    ln_u += 0.693_359_4 * e;
    let denominator = u - 1.0;
    let corrected = if denominator == 0.0 {
        y
    } else {
        ln_u * (y / denominator)
    };
    // Infinity and NaN pass through as libm's would.
    if y.is_finite() { corrected } else { y }
}

/// `log σ(x) = min(x, 0) − ln(1 + e^{−|x|})`, stable for any `x` (never `ln 0`).
#[inline(always)]
pub fn log_sigmoid(x: f32) -> f32 {
    let value = x.min(0.0) - log1p(exp(-x.abs()));
    if x.is_nan() { x } else { value }
}

/// `(log σ(x), log σ(−x))`, equal to two calls of `log_sigmoid` but with their shared term
/// `ln(1 + e^{−|x|})` computed once: volume rendering needs both for every sample.
#[inline(always)]
pub fn log_sigmoid_pair(x: f32) -> (f32, f32) {
    let shared = log1p(exp(-x.abs()));
    let positive = x.min(0.0) - shared;
    let negative = (-x).min(0.0) - shared;
    if x.is_nan() {
        (x, x)
    } else {
        (positive, negative)
    }
}
