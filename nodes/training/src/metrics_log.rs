//! `RUN/metrics.csv`: one row per logged training step and per validation, appended and
//! flushed as the run goes, so that a crashed run keeps its curve. A trainer names its columns
//! once; a row gives values by column name, and the columns a row has no value for are empty.
//! Readers find columns by their header name, so a column added later (at the end, keeping
//! the positions of older logs) changes nothing for them.

use std::io::Write;
use std::path::{Path, PathBuf};

/// The columns every log starts with, and the one it ends its fixed part with.
pub const STEP: &str = "step";
pub const PHASE: &str = "phase";
pub const ELAPSED: &str = "elapsed_s";

#[derive(Debug, thiserror::Error)]
pub enum MetricsLogError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: a row has a value for `{column}`, which is not one of the log's columns")]
    UnknownColumn { path: PathBuf, column: String },
    #[error("{path}: the header has no `{column}` column")]
    MissingColumn { path: PathBuf, column: String },
}

pub struct MetricsLog {
    path: PathBuf,
    columns: Vec<&'static str>,
    /// Seconds the run had trained before this session: a resumed run's times continue from
    /// its last kept row, so `elapsed_s` is the run's training time across interruptions.
    elapsed_before_s: f64,
}

/// One row: its step and phase (`train`, `val`, …), the seconds since the run started, and
/// values by column name. Columns without a value are written empty.
#[derive(Clone, Debug, Default)]
pub struct Row {
    pub step: usize,
    pub phase: &'static str,
    pub elapsed_s: f64,
    pub values: Vec<(&'static str, f64)>,
}

impl MetricsLog {
    /// Opens `RUN/metrics.csv` with `columns` (which must hold `step`, `phase` and
    /// `elapsed_s`), writing the header if the file is new. On resume, rows after
    /// `resume_step` (a crashed run's steps beyond its last checkpoint) are dropped, so the
    /// curve has no duplicates, and the rows appended from then on add the kept rows' last
    /// elapsed time to their own.
    pub fn open(
        run: &Path,
        columns: &[&'static str],
        resume_step: Option<usize>,
    ) -> Result<Self, MetricsLogError> {
        let path = run.join("metrics.csv");
        let io = |source| MetricsLogError::Io {
            path: path.clone(),
            source,
        };
        let (kept, elapsed_before_s) = match (resume_step, std::fs::read_to_string(&path)) {
            (Some(step), Ok(text)) => {
                let mut lines = text.lines();
                let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
                let field = |line: &str, column: &str| {
                    let at = header.iter().position(|c| *c == column)?;
                    line.split(',').nth(at).map(str::to_string)
                };
                let kept: Vec<&str> = lines
                    .filter(|line| {
                        field(line, STEP)
                            .and_then(|s| s.parse::<usize>().ok())
                            .is_some_and(|s| s <= step)
                    })
                    .collect();
                let elapsed = kept
                    .iter()
                    .filter_map(|line| field(line, ELAPSED)?.parse::<f64>().ok())
                    .filter(|s| s.is_finite())
                    .fold(0.0, f64::max);
                (
                    kept.iter().map(|l| format!("{l}\n")).collect::<String>(),
                    elapsed,
                )
            }
            _ => (String::new(), 0.0),
        };
        for column in [STEP, PHASE, ELAPSED] {
            if !columns.contains(&column) {
                return Err(MetricsLogError::MissingColumn {
                    path,
                    column: column.into(),
                });
            }
        }
        bevworld_atomic_file::write(&path, format!("{}\n{kept}", columns.join(",")).as_bytes())
            .map_err(io)?;
        Ok(Self {
            path,
            columns: columns.to_vec(),
            elapsed_before_s,
        })
    }

    pub fn append(&mut self, row: &Row) -> Result<(), MetricsLogError> {
        if let Some((column, _)) = row
            .values
            .iter()
            .find(|(column, _)| !self.columns.contains(column))
        {
            return Err(MetricsLogError::UnknownColumn {
                path: self.path.clone(),
                column: (*column).into(),
            });
        }
        let fields: Vec<String> = self
            .columns
            .iter()
            .map(|&column| match column {
                STEP => row.step.to_string(),
                PHASE => row.phase.to_string(),
                ELAPSED => format!("{:.1}", self.elapsed_before_s + row.elapsed_s),
                _ => row
                    .values
                    .iter()
                    .find(|(name, _)| *name == column)
                    .map(|(_, v)| format!("{v:.6}"))
                    .unwrap_or_default(),
            })
            .collect();
        let io = |source| MetricsLogError::Io {
            path: self.path.clone(),
            source,
        };
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.path)
            .map_err(io)?;
        file.write_all(format!("{}\n", fields.join(",")).as_bytes())
            .map_err(io)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The `(step, value)` points of column `column` over the rows of phase `phase`, read by the
/// header's names. Empty and unparsable fields are skipped.
pub fn read_series(
    path: &Path,
    phase: &str,
    column: &str,
) -> Result<Vec<(f64, f64)>, MetricsLogError> {
    let text = std::fs::read_to_string(path).map_err(|source| MetricsLogError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let find = |name: &str| {
        header
            .iter()
            .position(|c| *c == name)
            .ok_or_else(|| MetricsLogError::MissingColumn {
                path: path.to_path_buf(),
                column: name.into(),
            })
    };
    let (step, phase_at, value_at) = (find(STEP)?, find(PHASE)?, find(column)?);
    Ok(lines
        .filter_map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            if fields.get(phase_at) != Some(&phase) {
                return None;
            }
            let number = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok());
            Some((number(step)?, number(value_at)?))
        })
        .collect())
}
