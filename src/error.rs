//! The crate's one error type. Every variant that concerns a file names it, so a
//! user reading the message knows which input to fix.

use std::path::{Path, PathBuf};

/// Everything that can go wrong in lumiprobe.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused a read or write.
    #[error("{path}: {source}")]
    Io {
        /// File that was being read or written.
        path: PathBuf,
        /// What the OS said.
        #[source]
        source: std::io::Error,
    },
    /// A file exists but its contents are not what its format promises.
    #[error("{path}: {msg}")]
    Format {
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it.
        msg: String,
    },
    /// An image declares more pixels than the configured limit allows.
    #[error("{path}: image of {width}x{height} exceeds the pixel limit of {limit}")]
    TooLarge {
        /// The offending file.
        path: PathBuf,
        /// Declared width.
        width: u64,
        /// Declared height.
        height: u64,
        /// The limit in pixels.
        limit: u64,
    },
    /// A caller passed arguments that cannot work (sizes that do not match, …).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// The OpenCV layer threw; the C++ message is kept.
    #[error("OpenCV: {0}")]
    OpenCv(String),
}

/// Shorthand used throughout the crate.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A format error for `path`.
    pub fn format(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
    /// An I/O error for `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        let path = path.as_ref();
        // Making a folder where a file stands ("File exists"): say so.
        if source.kind() == std::io::ErrorKind::AlreadyExists && path.is_file() {
            return Error::format(
                path,
                "is a file where a folder is needed: give a folder, or move the file away",
            );
        }
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}
