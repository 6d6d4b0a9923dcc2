//! The Fréchet distance between two Gaussians fitted to feature sets, as FID computes it:
//!
//! `d² = |mu1 - mu2|² + Tr(S1 + S2 - 2 (S1^½ S2 S1^½)^½)`
//!
//! The trace of the matrix square root uses the symmetric form `S1^½ S2 S1^½`, whose eigenvalues
//! are those of `S1 S2`, so only symmetric eigendecompositions (cyclic Jacobi, exact to
//! round-off) are needed. Cost is O(d³) per Jacobi sweep: minutes at d = 2048.
//!
//! With fewer samples than dimensions (the usual case for evaluation sets up to a few thousand
//! images at d = 2048), `frechet_distance_of_features` takes the exact low-rank route instead:
//! with `S1 = A Aᵀ` and `S2 = B Bᵀ` (A, B the centred samples over `√(n − 1)`), the non-zero
//! eigenvalues of `S1 S2` are the squared singular values of `Bᵀ A`, an `n2 x n1` matrix.
//!
//! FID is this distance over InceptionV3 pool features; the extractor is pluggable through
//! `FeatureExtractor`, so the maths is tested on its own.

/// Turns an image into a feature vector (InceptionV3 pool3 for FID).
pub trait FeatureExtractor {
    type Error: std::error::Error;
    fn name(&self) -> &str;
    fn dimension(&self) -> usize;
    fn features(&self, image: &image::RgbImage) -> Result<Vec<f64>, Self::Error>;
}

/// Why a Fréchet distance could not be computed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrechetError {
    #[error("need at least 2 feature vectors, got {0}")]
    TooFew(usize),
    #[error("feature vectors must be non-empty and of equal length")]
    Ragged,
    #[error("feature vectors contain non-finite values")]
    NonFinite,
    #[error("feature dimensions differ: {0} vs {1}")]
    Dimensions(usize, usize),
}

/// Checks a feature set (at least two rows of one non-zero length, all finite) and returns its
/// row count, dimension and mean.
fn checked_mean(rows: &[Vec<f64>]) -> Result<(usize, usize, Vec<f64>), FrechetError> {
    let n = rows.len();
    if n < 2 {
        return Err(FrechetError::TooFew(n));
    }
    let d = rows[0].len();
    if d == 0 || rows.iter().any(|r| r.len() != d) {
        return Err(FrechetError::Ragged);
    }
    if rows.iter().flatten().any(|v| !v.is_finite()) {
        return Err(FrechetError::NonFinite);
    }
    let mut mean = vec![0.0; d];
    for row in rows {
        for (m, v) in mean.iter_mut().zip(row) {
            *m += v / n as f64;
        }
    }
    Ok((n, d, mean))
}

/// Mean and covariance of a feature set.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussianStats {
    pub mean: Vec<f64>,
    /// Row-major `d x d`, with the unbiased (n - 1) normalisation, as numpy's `np.cov`.
    pub covariance: Vec<f64>,
    pub count: usize,
}

impl GaussianStats {
    pub fn dimension(&self) -> usize {
        self.mean.len()
    }

    /// Fits rows of equal length; needs at least two.
    pub fn fit(rows: &[Vec<f64>]) -> Result<Self, FrechetError> {
        let (n, d, mean) = checked_mean(rows)?;
        let mut covariance = vec![0.0; d * d];
        for row in rows {
            for i in 0..d {
                let di = row[i] - mean[i];
                for j in i..d {
                    covariance[i * d + j] += di * (row[j] - mean[j]);
                }
            }
        }
        for i in 0..d {
            for j in i..d {
                let value = covariance[i * d + j] / (n - 1) as f64;
                covariance[i * d + j] = value;
                covariance[j * d + i] = value;
            }
        }
        Ok(Self {
            mean,
            covariance,
            count: n,
        })
    }
}

/// Eigenvalues and eigenvectors (columns of the row-major `d x d` result) of a symmetric
/// matrix, by cyclic Jacobi rotations.
pub fn symmetric_eigen(matrix: &[f64], d: usize) -> (Vec<f64>, Vec<f64>) {
    let mut a = matrix.to_vec();
    let mut v = vec![0.0; d * d];
    for i in 0..d {
        v[i * d + i] = 1.0;
    }
    let norm: f64 = a
        .iter()
        .map(|x| x * x)
        .sum::<f64>()
        .sqrt()
        .max(f64::MIN_POSITIVE);
    for _sweep in 0..100 {
        let off: f64 = (0..d)
            .flat_map(|i| (0..d).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i * d + j].powi(2))
            .sum::<f64>()
            .sqrt();
        if off <= 1e-15 * norm {
            break;
        }
        for p in 0..d {
            for q in p + 1..d {
                let apq = a[p * d + q];
                if apq.abs() <= 1e-300 {
                    continue;
                }
                let theta = (a[q * d + q] - a[p * d + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..d {
                    let (akp, akq) = (a[k * d + p], a[k * d + q]);
                    a[k * d + p] = c * akp - s * akq;
                    a[k * d + q] = s * akp + c * akq;
                }
                for k in 0..d {
                    let (apk, aqk) = (a[p * d + k], a[q * d + k]);
                    a[p * d + k] = c * apk - s * aqk;
                    a[q * d + k] = s * apk + c * aqk;
                }
                for k in 0..d {
                    let (vkp, vkq) = (v[k * d + p], v[k * d + q]);
                    v[k * d + p] = c * vkp - s * vkq;
                    v[k * d + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..d).map(|i| a[i * d + i]).collect(), v)
}

/// The symmetric square root of a symmetric positive semi-definite matrix (negative
/// eigenvalues from round-off are clamped to 0).
pub fn sqrt_psd(matrix: &[f64], d: usize) -> Vec<f64> {
    let (values, vectors) = symmetric_eigen(matrix, d);
    let roots: Vec<f64> = values.iter().map(|v| v.max(0.0).sqrt()).collect();
    let mut out = vec![0.0; d * d];
    for i in 0..d {
        for j in 0..d {
            out[i * d + j] = (0..d)
                .map(|k| vectors[i * d + k] * roots[k] * vectors[j * d + k])
                .sum();
        }
    }
    out
}

fn matmul(a: &[f64], b: &[f64], d: usize) -> Vec<f64> {
    let mut out = vec![0.0; d * d];
    for i in 0..d {
        for k in 0..d {
            let aik = a[i * d + k];
            for j in 0..d {
                out[i * d + j] += aik * b[k * d + j];
            }
        }
    }
    out
}

/// The squared Fréchet distance between two fitted Gaussians.
pub fn frechet_distance(a: &GaussianStats, b: &GaussianStats) -> Result<f64, FrechetError> {
    let d = a.dimension();
    if b.dimension() != d {
        return Err(FrechetError::Dimensions(d, b.dimension()));
    }
    let mean_term: f64 = a
        .mean
        .iter()
        .zip(&b.mean)
        .map(|(x, y)| (x - y).powi(2))
        .sum();
    let root_a = sqrt_psd(&a.covariance, d);
    let inner = matmul(&matmul(&root_a, &b.covariance, d), &root_a, d);
    // Symmetrise away round-off before the second decomposition.
    let inner: Vec<f64> = (0..d * d)
        .map(|k| 0.5 * (inner[k] + inner[(k % d) * d + k / d]))
        .collect();
    let (values, _) = symmetric_eigen(&inner, d);
    let trace_root: f64 = values.iter().map(|v| v.max(0.0).sqrt()).sum();
    let trace = |m: &[f64]| (0..d).map(|i| m[i * d + i]).sum::<f64>();
    Ok((mean_term + trace(&a.covariance) + trace(&b.covariance) - 2.0 * trace_root).max(0.0))
}

/// Centred samples over `√(n − 1)`, row-major `[n, d]`, and their mean: `S = Aᵀ A` for these rows.
fn centred_scaled(rows: &[Vec<f64>]) -> Result<(Vec<f64>, Vec<f64>), FrechetError> {
    let (n, d, mean) = checked_mean(rows)?;
    let scale = 1.0 / ((n - 1) as f64).sqrt();
    let mut a = Vec::with_capacity(n * d);
    for row in rows {
        a.extend(row.iter().zip(&mean).map(|(v, m)| (v - m) * scale));
    }
    Ok((a, mean))
}

/// The squared Fréchet distance between the Gaussians of two feature sets (rows of equal
/// length, at least two per set). Exact either way; the low-rank route is taken when a set has
/// fewer samples than dimensions.
pub fn frechet_distance_of_features(a: &[Vec<f64>], b: &[Vec<f64>]) -> Result<f64, FrechetError> {
    let (n1, n2) = (a.len(), b.len());
    let d = a.first().map_or(0, Vec::len);
    if b.first().map_or(0, Vec::len) != d {
        return Err(FrechetError::Dimensions(d, b.first().map_or(0, Vec::len)));
    }
    if n1.min(n2) >= d {
        return frechet_distance(&GaussianStats::fit(a)?, &GaussianStats::fit(b)?);
    }
    let (sa, mean_a) = centred_scaled(a)?; // [n1, d]
    let (sb, mean_b) = centred_scaled(b)?; // [n2, d]
    let mean_term: f64 = mean_a
        .iter()
        .zip(&mean_b)
        .map(|(x, y)| (x - y).powi(2))
        .sum();
    let trace_a: f64 = sa.iter().map(|v| v * v).sum();
    let trace_b: f64 = sb.iter().map(|v| v * v).sum();
    // M = B Aᵀ in row terms: M[j][i] = <b_j, a_i>, an n2 x n1 matrix.
    let mut m = vec![0.0; n2 * n1];
    for j in 0..n2 {
        let bj = &sb[j * d..(j + 1) * d];
        for i in 0..n1 {
            let ai = &sa[i * d..(i + 1) * d];
            m[j * n1 + i] = bj.iter().zip(ai).map(|(x, y)| x * y).sum();
        }
    }
    // The smaller Gram matrix of M has the squared singular values as eigenvalues.
    let (gram, k) = if n1 <= n2 {
        let mut g = vec![0.0; n1 * n1];
        for p in 0..n1 {
            for q in 0..n1 {
                g[p * n1 + q] = (0..n2).map(|j| m[j * n1 + p] * m[j * n1 + q]).sum();
            }
        }
        (g, n1)
    } else {
        let mut g = vec![0.0; n2 * n2];
        for p in 0..n2 {
            for q in 0..n2 {
                g[p * n2 + q] = (0..n1).map(|i| m[p * n1 + i] * m[q * n1 + i]).sum();
            }
        }
        (g, n2)
    };
    let (values, _) = symmetric_eigen(&gram, k);
    let trace_root: f64 = values.iter().map(|v| v.max(0.0).sqrt()).sum();
    Ok((mean_term + trace_a + trace_b - 2.0 * trace_root).max(0.0))
}
