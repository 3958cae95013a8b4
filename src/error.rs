//! Typed errors for the library: every refusal names the file (and line/element where known)
//! and says what is wrong, in one line, so `main` can print it and exit non-zero.

use std::path::{Path, PathBuf};

/// Where in an input file a problem was found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Location {
    pub line: Option<u32>,
    pub col: Option<u32>,
    /// The XML element or OBJ/PLY record involved, e.g. `<shape type="obj">`.
    pub element: Option<String>,
}

/// The library's error type. `Display` is always a single line.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Malformed or unsupported content in an input file.
    #[error("{}", fmt_input(.path, .loc, .msg))]
    Input {
        path: PathBuf,
        loc: Location,
        msg: String,
    },
    /// An OS-level failure reading or writing a file.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Settings that cannot work together (not tied to one file).
    #[error("invalid settings: {0}")]
    Config(String),
}

fn fmt_input(path: &Path, loc: &Location, msg: &str) -> String {
    let mut s = path.display().to_string();
    if let Some(l) = loc.line {
        s.push_str(&format!(" (line {l}"));
        if let Some(c) = loc.col {
            s.push_str(&format!(", col {c}"));
        }
        s.push(')');
    }
    if let Some(e) = &loc.element {
        s.push_str(&format!(", {e}"));
    }
    s.push_str(": ");
    // keep it one line whatever the message holds
    s.push_str(&msg.replace('\n', " "));
    s
}

impl Error {
    /// An input error with no line information.
    pub fn input(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            loc: Location::default(),
            msg: msg.into(),
        }
    }

    /// An input error at a line (1-based).
    pub fn input_at(path: impl Into<PathBuf>, line: u32, msg: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            loc: Location {
                line: Some(line),
                ..Default::default()
            },
            msg: msg.into(),
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn input_error_is_one_line_with_location() {
        let e = Error::Input {
            path: "scene.xml".into(),
            loc: Location {
                line: Some(10),
                col: Some(5),
                element: Some("<shape type=\"foo\">".into()),
            },
            msg: "unsupported\nplugin".into(),
        };
        let s = e.to_string();
        assert_eq!(
            s,
            "scene.xml (line 10, col 5), <shape type=\"foo\">: unsupported plugin"
        );
        assert!(!s.contains('\n'));
    }
}
