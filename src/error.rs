//! Typed errors for every stage, and the documented process exit codes.
//!
//! Library code returns [`Error`]; `main` maps it to an exit code with [`Error::exit_code`].
//! Every error that comes from a file names the file and the place in it (line, byte offset, chunk).
#![warn(missing_docs)]

use std::path::{Path, PathBuf};

/// Exit codes of the `bake` binary (documented in README.md).
pub mod exit {
    /// Success.
    pub const OK: i32 = 0;
    /// Bad command line (clap also uses 2).
    pub const USAGE: i32 = 2;
    /// A file could not be read or written.
    pub const IO: i32 = 3;
    /// An input file is malformed or unsupported.
    pub const INVALID_INPUT: i32 = 4;
    /// Anything else that failed while running (GPU not available, numerical failure...).
    pub const RUNTIME: i32 = 5;
}

/// A parse failure inside a byte buffer, before the file name is known.
///
/// Readers take `&[u8]` and return this; [`Error::invalid`] attaches the path.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{place}: {message}")]
pub struct ParseError {
    /// Where in the input: "line 12", "byte 0x1a4 (chunk 0x4110)", ...
    pub place: String,
    /// What was expected or what went wrong.
    pub message: String,
}

impl ParseError {
    /// A failure at `place` (free text) with `message`.
    pub fn new(place: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            place: place.into(),
            message: message.into(),
        }
    }
    /// A failure at a line (1-based).
    pub fn at_line(line: usize, message: impl Into<String>) -> Self {
        Self::new(format!("line {line}"), message)
    }
    /// A failure at a byte offset.
    pub fn at_byte(offset: usize, message: impl Into<String>) -> Self {
        Self::new(format!("byte {offset}"), message)
    }
}

/// Every error the library returns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad arguments or options (exit code 2); the message says which and what is expected.
    #[error("{0}")]
    Usage(String),
    /// A file could not be read or written (exit code 3).
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// An input is not what its format requires (exit code 4).
    #[error("{}: {source}", path.display())]
    Invalid {
        /// The input file (or the pack a section came from).
        path: PathBuf,
        /// Where in it and what is wrong.
        source: ParseError,
    },
    /// Anything else that failed while running (exit code 5): no GPU, a failed bake step.
    #[error("{0}")]
    Runtime(String),
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    /// An invalid-input error in `path`.
    pub fn invalid(path: impl AsRef<Path>, source: ParseError) -> Self {
        Error::Invalid {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    /// An invalid-input error with a place and a message.
    pub fn invalid_at(
        path: impl AsRef<Path>,
        place: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Self::invalid(path, ParseError::new(place, message))
    }
    /// A usage error.
    pub fn usage(message: impl Into<String>) -> Self {
        Error::Usage(message.into())
    }
    /// A runtime error.
    pub fn runtime(message: impl Into<String>) -> Self {
        Error::Runtime(message.into())
    }
    /// The process exit code for this error (see [`exit`]).
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Usage(_) => exit::USAGE,
            Error::Io { .. } => exit::IO,
            Error::Invalid { .. } => exit::INVALID_INPUT,
            Error::Runtime(_) => exit::RUNTIME,
        }
    }
}

/// The library's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Reads a whole file, mapping the error to [`Error::Io`] with the path.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}
