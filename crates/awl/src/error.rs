//! The library's error type: every variant names the file, field or input it is about.

use std::path::PathBuf;

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What went wrong, with enough context (file, field) for a user to fix it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A file's content is malformed (bad header, truncated body, wrong encoding).
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where in the file.
        message: String,
    },
    /// One field of a structured file (JSON manifest, header) has an invalid value.
    #[error("{path}: field `{field}`: {message}")]
    Field {
        /// The file.
        path: PathBuf,
        /// The field, as a path such as `views[3].T_world_base`.
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// An in-memory input or parameter is invalid (empty cloud, bad option).
    #[error("{what}: {message}")]
    Invalid {
        /// The input or parameter.
        what: String,
        /// What is wrong with it.
        message: String,
    },
    /// A computed figure is not a finite number (NaN or infinite): a result holding it would mean
    /// nothing, so none is given.
    #[error("{what} is not finite: {message}")]
    NotFinite {
        /// The figure (`the RMSE of the on-object points`).
        what: String,
        /// Why, and what to check.
        message: String,
    },
    /// A robot controller could not be reached, did not answer in time, or refused what was sent.
    #[error("robot controller {address}: {message}")]
    Robot {
        /// The controller's address (`host:port`).
        address: String,
        /// What happened, and what was being sent.
        message: String,
    },
}

impl Error {
    /// An [`Error::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
    /// An [`Error::Format`] for `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format { path: path.into(), message: message.into() }
    }
    /// An [`Error::Robot`] for the controller at `address`.
    pub fn robot(address: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Robot { address: address.into(), message: message.into() }
    }
    /// An [`Error::Field`] for `field` of `path`.
    pub fn field(path: impl Into<PathBuf>, field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Field { path: path.into(), field: field.into(), message: message.into() }
    }
    /// An [`Error::Invalid`] about `what`.
    pub fn invalid(what: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid { what: what.into(), message: message.into() }
    }
}
