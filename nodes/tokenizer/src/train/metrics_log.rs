//! `RUN/metrics.csv`: one row per logged training step and per validation, appended and
//! flushed as the run goes, so that a crashed run keeps its curve. Columns that do not apply
//! to a row are empty. A column added later goes at the end, so that the positions of the
//! others stay those of older logs.

use std::io::Write;
use std::path::{Path, PathBuf};

pub const HEADER: &str = "step,phase,lr,loss,loss_rgb,loss_lidar,loss_perceptual,loss_gan,loss_discriminator,grad_norm,psnr_db,ssim,chamfer_m2,elapsed_s,loss_distortion,loss_termination,loss_rgb_squared";

pub struct MetricsLog {
    path: PathBuf,
}

/// One row; `None` fields are written empty.
#[derive(Clone, Debug, Default)]
pub struct Row {
    pub step: usize,
    pub phase: &'static str,
    pub lr: Option<f64>,
    pub loss: Option<f64>,
    pub loss_rgb: Option<f64>,
    pub loss_lidar: Option<f64>,
    pub loss_perceptual: Option<f64>,
    pub loss_gan: Option<f64>,
    pub loss_discriminator: Option<f64>,
    pub grad_norm: Option<f64>,
    pub psnr_db: Option<f64>,
    pub ssim: Option<f64>,
    pub chamfer_m2: Option<f64>,
    pub elapsed_s: f64,
    pub loss_distortion: Option<f64>,
    pub loss_termination: Option<f64>,
    pub loss_rgb_squared: Option<f64>,
}

impl MetricsLog {
    /// Opens the log, writing the header if the file is new. On resume, rows after `step` (a
    /// crashed run's steps beyond its last checkpoint) are dropped, so the curve has no
    /// duplicates.
    pub fn open(run: &Path, resume_step: Option<usize>) -> std::io::Result<Self> {
        let path = run.join("metrics.csv");
        let kept = match (resume_step, std::fs::read_to_string(&path)) {
            (Some(step), Ok(text)) => text
                .lines()
                .skip(1)
                .filter(|line| {
                    line.split(',')
                        .next()
                        .and_then(|s| s.parse::<usize>().ok())
                        .is_some_and(|s| s <= step)
                })
                .map(|l| format!("{l}\n"))
                .collect::<String>(),
            _ => String::new(),
        };
        std::fs::write(&path, format!("{HEADER}\n{kept}"))?;
        Ok(Self { path })
    }

    pub fn append(&mut self, row: &Row) -> std::io::Result<()> {
        let f = |v: Option<f64>| v.map(|v| format!("{v:.6}")).unwrap_or_default();
        let line = format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1},{},{},{}\n",
            row.step,
            row.phase,
            f(row.lr),
            f(row.loss),
            f(row.loss_rgb),
            f(row.loss_lidar),
            f(row.loss_perceptual),
            f(row.loss_gan),
            f(row.loss_discriminator),
            f(row.grad_norm),
            f(row.psnr_db),
            f(row.ssim),
            f(row.chamfer_m2),
            row.elapsed_s,
            f(row.loss_distortion),
            f(row.loss_termination),
            f(row.loss_rgb_squared)
        );
        let mut file = std::fs::OpenOptions::new().append(true).open(&self.path)?;
        file.write_all(line.as_bytes())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_row_has_the_headers_columns_in_order() {
        let dir = std::env::temp_dir().join(format!("bevworld-metrics-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let mut log = MetricsLog::open(&dir, None).expect("open");
        log.append(&Row {
            step: 7,
            phase: "val",
            psnr_db: Some(21.5),
            chamfer_m2: Some(0.25),
            elapsed_s: 3.0,
            ..Row::default()
        })
        .expect("append");
        let text = std::fs::read_to_string(log.path()).expect("read");
        let _ = std::fs::remove_dir_all(&dir);
        let lines: Vec<Vec<&str>> = text.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(lines[0].len(), lines[1].len(), "{text}");
        let column = |name: &str| lines[0].iter().position(|c| *c == name).expect(name);
        assert_eq!(lines[1][column("psnr_db")], "21.500000");
        assert_eq!(lines[1][column("chamfer_m2")], "0.250000");
        assert_eq!(lines[1][column("elapsed_s")], "3.0");
        assert_eq!(lines[1][column("ssim")], "");
    }
}
