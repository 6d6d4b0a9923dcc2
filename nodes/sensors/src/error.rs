//! Reader errors. Each names the file, and the record and field where there is one.

use std::path::PathBuf;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum SensorError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not valid JSON for table '{table}': {message}")]
    Table {
        path: PathBuf,
        table: &'static str,
        message: String,
    },
    #[error("{path}: {record}: field '{field}': {message}")]
    Field {
        path: PathBuf,
        record: String,
        field: &'static str,
        message: String,
    },
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("{path}: corrupt image: {message}")]
    Image { path: PathBuf, message: String },
    #[error("{0}")]
    Other(String),
}

impl SensorError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    pub fn file(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::File {
            path: path.into(),
            message: message.into(),
        }
    }

    pub fn field(
        path: impl Into<PathBuf>,
        record: impl Into<String>,
        field: &'static str,
        message: impl Into<String>,
    ) -> Self {
        Self::Field {
            path: path.into(),
            record: record.into(),
            field,
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, SensorError>;
