//! Typed errors for the library: every refusal names the file (and line/element where known)
//! and says what is wrong, in one line, so `main` can print it and exit with the code of its
//! kind ([`Error::exit_code`], sysexits-style, listed in the README's "Exit codes").

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
    /// Malformed or unsupported content in an input file (scene, mesh, photo, run config).
    #[error("{}", fmt_input(.path, .loc, .msg))]
    Input {
        path: PathBuf,
        loc: Location,
        msg: String,
    },
    /// An OS-level failure reading or writing a file (missing file, full disk, permissions).
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// State kdmap wrote itself and finds damaged: a checkpoint, a snapshot or a tile store
    /// (torn, truncated, bad checksum, another format version).
    #[error("{}: {}", .path.display(), .msg.replace('\n', " "))]
    Corrupt { path: PathBuf, msg: String },
    /// Settings that cannot work (alone or together), with the file that holds them if any.
    #[error("{}", fmt_config(.path, .msg))]
    Config { path: Option<PathBuf>, msg: String },
    /// A broken invariant inside kdmap (a bug): never the user's input.
    #[error("internal error: {}", .0.replace('\n', " "))]
    Internal(String),
    /// Stopped at a safe point after SIGINT or SIGTERM (`interrupt`); the message says what
    /// was saved and how to continue.
    #[error("interrupted: {}", .0.replace('\n', " "))]
    Interrupted(String),
    /// A run asked to be strict (`--strict`) finished, its outputs written, with a warning.
    #[error("--strict: {}", .0.replace('\n', " "))]
    Strict(String),
    /// An error another rank of an MPI job met (`comm`), passed on so that every rank ends
    /// with its exit code; rank 0 prints it.
    #[error("rank {rank}: {}", .msg.replace('\n', " "))]
    Rank { rank: usize, code: u8, msg: String },
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

fn fmt_config(path: &Option<PathBuf>, msg: &str) -> String {
    let msg = msg.replace('\n', " ");
    match path {
        Some(p) => format!("{}: {msg}", p.display()),
        None => format!("invalid settings: {msg}"),
    }
}

/// Exit codes of the command line, one per error kind (BSD sysexits where one fits).
pub mod exit {
    /// Success.
    pub const OK: u8 = 0;
    /// Bad command-line usage (clap).
    pub const USAGE: u8 = 2;
    /// An input file is malformed or unsupported (EX_DATAERR).
    pub const INPUT: u8 = 65;
    /// An input file does not exist (EX_NOINPUT).
    pub const MISSING: u8 = 66;
    /// A bug in kdmap (EX_SOFTWARE).
    pub const INTERNAL: u8 = 70;
    /// Reading or writing a file failed: full disk, permissions, ... (EX_IOERR).
    pub const IO: u8 = 74;
    /// kdmap's own saved state is damaged: checkpoint, snapshot or tile store (EX_TEMPFAIL:
    /// run again without `--resume`).
    pub const CORRUPT: u8 = 75;
    /// Impossible settings (EX_CONFIG).
    pub const CONFIG: u8 = 78;
    /// Another rank of an MPI job died (EX_UNAVAILABLE); the launcher ends the job.
    pub const RANK_DIED: u8 = 69;
    /// A `--strict` run finished with a warning; its outputs are written.
    pub const STRICT: u8 = 3;
    /// Stopped by SIGINT or SIGTERM (128 + 2).
    pub const INTERRUPTED: u8 = 130;
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

    pub fn corrupt(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Corrupt {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// Settings that cannot work, not tied to a file.
    pub fn config(msg: impl Into<String>) -> Self {
        Error::Config {
            path: None,
            msg: msg.into(),
        }
    }

    /// Settings that cannot work, as written in `path` (a run config or the scene).
    pub fn config_in(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Config {
            path: Some(path.into()),
            msg: msg.into(),
        }
    }

    pub fn internal(msg: impl Into<String>) -> Self {
        Error::Internal(msg.into())
    }

    /// The command line's exit code for this error (see [`exit`]).
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Input { .. } => exit::INPUT,
            Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                exit::MISSING
            }
            Error::Io { .. } => exit::IO,
            Error::Corrupt { .. } => exit::CORRUPT,
            Error::Config { .. } => exit::CONFIG,
            Error::Internal(_) => exit::INTERNAL,
            Error::Interrupted(_) => exit::INTERRUPTED,
            Error::Strict(_) => exit::STRICT,
            Error::Rank { code, .. } => *code,
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

    #[test]
    fn every_kind_has_its_own_exit_code_and_one_line() {
        let missing = std::io::Error::from(std::io::ErrorKind::NotFound);
        let full = std::io::Error::from_raw_os_error(28);
        let errors = [
            (Error::input("a.xml", "bad"), exit::INPUT),
            (Error::io("a.obj", missing), exit::MISSING),
            (Error::io("out/x.exr", full), exit::IO),
            (Error::corrupt("state.tiles", "bad\nmagic"), exit::CORRUPT),
            (Error::config("photons = 0"), exit::CONFIG),
            (Error::config_in("run.toml", "photons = 0"), exit::CONFIG),
            (Error::internal("tile 9 of 3"), exit::INTERNAL),
            (Error::Interrupted("at batch 3".into()), exit::INTERRUPTED),
        ];
        let mut codes: Vec<u8> = errors.iter().map(|(e, _)| e.exit_code()).collect();
        for (e, code) in &errors {
            assert_eq!(e.exit_code(), *code, "{e}");
            assert!(!e.to_string().contains('\n'), "{e}");
        }
        codes.sort();
        codes.dedup();
        assert_eq!(
            codes.len(),
            7,
            "input, missing, io, corrupt, config, internal, interrupted"
        );
        assert_eq!(
            Error::config_in("run.toml", "photons = 0").to_string(),
            "run.toml: photons = 0"
        );
        assert!(Error::corrupt("s.tiles", "bad")
            .to_string()
            .starts_with("s.tiles: "));
    }
}
