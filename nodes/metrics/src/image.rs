//! Image metrics: PSNR with an explicit data range, and SSIM (Wang et al. 2004).

/// Why two images could not be compared.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ImageMetricError {
    #[error("image data has {values} values, expected {channels}x{height}x{width}")]
    Length {
        values: usize,
        channels: usize,
        height: usize,
        width: usize,
    },
    #[error("images differ in shape: {a:?} vs {b:?} (channels, height, width)")]
    Shape {
        a: (usize, usize, usize),
        b: (usize, usize, usize),
    },
    #[error("data range must be a finite number > 0, got {0}")]
    DataRange(f64),
    #[error("empty images")]
    Empty,
    #[error("images contain non-finite values")]
    NonFinite,
    #[error("SSIM needs images of at least {window}x{window}, got {width}x{height}")]
    TooSmall {
        window: usize,
        width: usize,
        height: usize,
    },
}

/// An image as planar f32 channels, `[C, H, W]`.
#[derive(Clone, Debug)]
pub struct Planes<'a> {
    pub data: &'a [f32],
    pub channels: usize,
    pub height: usize,
    pub width: usize,
}

impl Planes<'_> {
    fn check(&self, other: &Planes) -> Result<(), ImageMetricError> {
        if self.data.len() != self.channels * self.height * self.width {
            return Err(ImageMetricError::Length {
                values: self.data.len(),
                channels: self.channels,
                height: self.height,
                width: self.width,
            });
        }
        let (a, b) = (
            (self.channels, self.height, self.width),
            (other.channels, other.height, other.width),
        );
        if a != b {
            return Err(ImageMetricError::Shape { a, b });
        }
        Ok(())
    }
}

/// Peak signal-to-noise ratio in dB for values spanning `data_range` (255 for 8-bit, 1 for
/// [0, 1]). Identical images give `f64::INFINITY`, never NaN.
pub fn psnr(a: &Planes, b: &Planes, data_range: f64) -> Result<f64, ImageMetricError> {
    a.check(b)?;
    b.check(a)?;
    if !(data_range > 0.0 && data_range.is_finite()) {
        return Err(ImageMetricError::DataRange(data_range));
    }
    if a.data.is_empty() {
        return Err(ImageMetricError::Empty);
    }
    let mse = a
        .data
        .iter()
        .zip(b.data)
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    if !mse.is_finite() {
        return Err(ImageMetricError::NonFinite);
    }
    if mse == 0.0 {
        return Ok(f64::INFINITY);
    }
    Ok(10.0 * (data_range * data_range / mse).log10())
}

/// An 8-bit RGB image as `[3, H, W]` planes in [0, 255].
pub fn rgb_planes(image: &image::RgbImage) -> Vec<f32> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let mut planes = vec![0.0f32; 3 * w * h];
    for (i, pixel) in image.pixels().enumerate() {
        for c in 0..3 {
            planes[c * w * h + i] = f32::from(pixel.0[c]);
        }
    }
    planes
}

const WINDOW: usize = 11;
const SIGMA: f64 = 1.5;

fn gaussian_window() -> [f64; WINDOW] {
    let mut weights = [0.0; WINDOW];
    let half = (WINDOW / 2) as f64;
    for (k, weight) in weights.iter_mut().enumerate() {
        *weight = (-((k as f64 - half).powi(2)) / (2.0 * SIGMA * SIGMA)).exp();
    }
    let total: f64 = weights.iter().sum();
    weights.map(|w| w / total)
}

/// Separable Gaussian filter over the valid region (no padding): `[H - 10, W - 10]`.
fn filter(plane: &[f64], height: usize, width: usize, window: &[f64; WINDOW]) -> Vec<f64> {
    let (oh, ow) = (height - WINDOW + 1, width - WINDOW + 1);
    let mut rows = vec![0.0; height * ow];
    for y in 0..height {
        for x in 0..ow {
            rows[y * ow + x] = (0..WINDOW)
                .map(|k| window[k] * plane[y * width + x + k])
                .sum();
        }
    }
    let mut out = vec![0.0; oh * ow];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..WINDOW)
                .map(|k| window[k] * rows[(y + k) * ow + x])
                .sum();
        }
    }
    out
}

/// Mean SSIM over channels, with an 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03,
/// averaged over the valid region, as `skimage.metrics.structural_similarity` with
/// `gaussian_weights=True, use_sample_covariance=False` computes it.
pub fn ssim(a: &Planes, b: &Planes, data_range: f64) -> Result<f64, ImageMetricError> {
    a.check(b)?;
    b.check(a)?;
    if a.height < WINDOW || a.width < WINDOW {
        return Err(ImageMetricError::TooSmall {
            window: WINDOW,
            width: a.width,
            height: a.height,
        });
    }
    if !(data_range > 0.0 && data_range.is_finite()) {
        return Err(ImageMetricError::DataRange(data_range));
    }
    let window = gaussian_window();
    let (c1, c2) = ((0.01 * data_range).powi(2), (0.03 * data_range).powi(2));
    let plane = a.height * a.width;
    let mut total = 0.0;
    for c in 0..a.channels {
        let x: Vec<f64> = a.data[c * plane..(c + 1) * plane]
            .iter()
            .map(|v| f64::from(*v))
            .collect();
        let y: Vec<f64> = b.data[c * plane..(c + 1) * plane]
            .iter()
            .map(|v| f64::from(*v))
            .collect();
        let product =
            |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(u, v)| u * v).collect::<Vec<f64>>();
        let (mx, my) = (
            filter(&x, a.height, a.width, &window),
            filter(&y, a.height, a.width, &window),
        );
        let xx = filter(&product(&x, &x), a.height, a.width, &window);
        let yy = filter(&product(&y, &y), a.height, a.width, &window);
        let xy = filter(&product(&x, &y), a.height, a.width, &window);
        let mut sum = 0.0;
        for i in 0..mx.len() {
            let (vx, vy, cxy) = (
                xx[i] - mx[i] * mx[i],
                yy[i] - my[i] * my[i],
                xy[i] - mx[i] * my[i],
            );
            sum += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
        }
        total += sum / mx.len() as f64;
    }
    Ok(total / a.channels as f64)
}
