//! What can go wrong writing or reading the report folder.

use std::path::Path;

/// A report file that could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// Creating or writing a file or folder.
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    /// Writing a CSV, or reading `steps.csv` back.
    #[error("{path}: {source}")]
    Csv { path: String, source: ::csv::Error },
    /// A `steps.csv` that reads but cannot be reported on.
    #[error("{path}: {why}")]
    Steps { path: String, why: String },
    /// Drawing a plot.
    #[error(transparent)]
    Plot(#[from] charts::PlotError),
}

/// An I/O error on `path`, for `map_err`.
pub fn io(path: &Path) -> impl Fn(std::io::Error) -> ReportError {
    let path = path.display().to_string();
    move |source| ReportError::Io { path: path.clone(), source }
}

/// A CSV error on `path`, for `map_err`.
pub fn csv_error(path: &Path) -> impl Fn(::csv::Error) -> ReportError {
    let path = path.display().to_string();
    move |source| ReportError::Csv { path: path.clone(), source }
}
