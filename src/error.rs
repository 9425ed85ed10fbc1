//! The crate's one error type. Every variant that concerns a file names it, so a
//! user reading the message knows which input to fix.

use std::path::{Path, PathBuf};

/// Everything that can go wrong in lumiprobe, by what the caller can do about
/// it: fix a file ([`Error::Format`]) or the arguments ([`Error::Invalid`]),
/// convert the input to something supported ([`Error::Unsupported`]), shrink it
/// or raise a limit ([`Error::Limit`]), check the disk or permissions
/// ([`Error::Io`]), install or check an external tool ([`Error::External`]),
/// or report a bug ([`Error::Internal`]).
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
    /// An input asks for more than a limit allows (pixels, triangles, scene-graph
    /// visits, output size): nothing was allocated for it.
    #[error("{}{what} exceeds the limit of {limit}", at(path))]
    Limit {
        /// The offending file, when the input is one.
        path: Option<PathBuf>,
        /// What was asked for ("image of 2000x1000 pixels").
        what: String,
        /// The limit, with its unit ("1000 pixels").
        limit: String,
    },
    /// A caller passed arguments that cannot work (sizes that do not match, …).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// The input is valid but lumiprobe does not handle it (a pixel type, a
    /// compression, a texture format): convert it first.
    #[error("{}{msg}", at(path))]
    Unsupported {
        /// The file, when the input is one.
        path: Option<PathBuf>,
        /// What is not supported, and what to convert it to.
        msg: String,
    },
    /// An external tool or library failed (OpenCV, ffmpeg, COLMAP); its own
    /// message is kept.
    #[error("{tool}: {msg}")]
    External {
        /// The tool ("OpenCV", "ffmpeg", "COLMAP").
        tool: &'static str,
        /// What it said.
        msg: String,
    },
    /// A check inside lumiprobe failed on data it made itself: a bug, to be
    /// reported with the message.
    #[error("internal error: {0}")]
    Internal(String),
}

/// `"path: "` for a limit naming a file, nothing otherwise.
fn at(path: &Option<PathBuf>) -> String {
    path.as_ref()
        .map(|p| format!("{}: ", p.display()))
        .unwrap_or_default()
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
    /// OpenCV's failure (a C++ exception turned into a message at the bridge).
    pub fn opencv(msg: impl Into<String>) -> Self {
        Error::External {
            tool: "OpenCV",
            msg: msg.into(),
        }
    }
    /// A limit exceeded by `what`, in file `path` when there is one.
    pub fn limit(path: Option<&Path>, what: impl Into<String>, limit: impl Into<String>) -> Self {
        Error::Limit {
            path: path.map(Path::to_path_buf),
            what: what.into(),
            limit: limit.into(),
        }
    }
    /// Valid input that lumiprobe does not handle, in file `path` when there is
    /// one.
    pub fn unsupported(path: Option<&Path>, msg: impl Into<String>) -> Self {
        Error::Unsupported {
            path: path.map(Path::to_path_buf),
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

/// `value` as pretty JSON. Serialising lumiprobe's own reports fails only on a
/// bug, so a failure is [`Error::Internal`].
pub fn to_json<T: serde::Serialize + ?Sized>(value: &T) -> Result<String> {
    serde_json::to_string_pretty(value).map_err(|e| Error::Internal(format!("JSON: {e}")))
}
