//! The `--out` directory checked before any work, so a run that could not write its results
//! is refused in one line naming the directory instead of after loading and unwrapping the
//! scene: it must be (or become) a writable directory, empty or holding only what kdmap
//! writes there (a finished or interrupted run's outputs, `kdmap accuracy`'s).

use crate::base::error::{Error, Result};
use std::io::ErrorKind;
use std::path::Path;

/// What a run (and `kdmap accuracy`, and the held-out judge `tools/heldout.py`) writes at
/// the top of its output directory.
const OUTPUT_DIRS: &[&str] = &[
    "textures",
    "maps",
    "renders",
    "meshes",
    "checkpoint",
    "accuracy",
    "heldout",
    "report",
];
const OUTPUT_FILES: &[&str] = &[
    "scene.xml",
    "scene.glb",
    "report.json",
    "report.html",
    "report_convergence.svg",
    "report_convergence.png",
    "heldout_original.xml",
    "heldout_relit.xml",
    PROBE,
];
/// The file written and removed to learn whether the directory takes writes (a kill between
/// the two leaves it, so it counts as kdmap's).
const PROBE: &str = ".kdmap-write-probe";

/// Refuse `out` as an output directory unless it is, or can be made, a writable directory that
/// holds nothing but kdmap outputs. Creates it when missing.
pub fn check_out_dir(out: &Path) -> Result<()> {
    let fail = |kind: ErrorKind, msg: String| Err(Error::io(out, std::io::Error::new(kind, msg)));
    if out.exists() && !out.is_dir() {
        let msg = "exists and is not a directory; --out needs a directory for the results";
        return fail(ErrorKind::NotADirectory, msg.into());
    }
    if let Err(e) = std::fs::create_dir_all(out) {
        return fail(e.kind(), format!("cannot create the output directory: {e}"));
    }
    if let Some(name) = foreign_entry(out)? {
        let msg = format!(
            "holds '{name}', which kdmap did not write; --out needs a new or empty directory, \
             or one holding an earlier run's outputs"
        );
        return fail(ErrorKind::DirectoryNotEmpty, msg);
    }
    if let Err(e) = probe_write(&out.join(PROBE)) {
        return fail(
            e.kind(),
            format!("the output directory is not writable: {e}"),
        );
    }
    Ok(())
}

/// Whether kdmap writes an entry of this name, of this kind, at the top of an output
/// directory (temporary names of files being written included).
fn is_output(name: &str, is_dir: bool) -> bool {
    match is_dir {
        true => OUTPUT_DIRS.contains(&name),
        false => {
            let base = name.strip_suffix(".tmp").unwrap_or(name);
            OUTPUT_FILES.contains(&base)
        }
    }
}

/// The first entry of `dir` (by name) that is not a kdmap output, if any.
fn foreign_entry(dir: &Path) -> Result<Option<String>> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut foreign = Vec::new();
    for e in rd {
        let e = e.map_err(|e| Error::io(dir, e))?;
        let name = e.file_name().to_string_lossy().into_owned();
        let is_dir = e
            .file_type()
            .map_err(|err| Error::io(e.path(), err))?
            .is_dir();
        if !is_output(&name, is_dir) {
            foreign.push(name);
        }
    }
    foreign.sort();
    Ok(foreign.into_iter().next())
}

/// Create `path`, write a byte to it and remove it.
fn probe_write(path: &Path) -> std::io::Result<()> {
    use std::io::Write;
    let written = std::fs::File::create(path).and_then(|mut f| f.write_all(b"k"));
    let removed = std::fs::remove_file(path);
    written.and(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_an_empty_and_an_earlier_run_s_directory_are_accepted() {
        let tmp = tempfile::tempdir().unwrap();
        let new = tmp.path().join("a/b");
        check_out_dir(&new).unwrap();
        assert!(new.is_dir());
        assert_eq!(std::fs::read_dir(&new).unwrap().count(), 0, "probe left");
        for d in ["textures", "checkpoint", "accuracy", "report"] {
            std::fs::create_dir(new.join(d)).unwrap();
        }
        for f in ["report.json", "report.html", "scene.xml.tmp", PROBE] {
            std::fs::write(new.join(f), "x").unwrap();
        }
        check_out_dir(&new).unwrap();
    }

    #[test]
    fn a_file_and_a_foreign_entry_are_refused_naming_the_path() {
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp.path().join("out");
        std::fs::write(&file, "x").unwrap();
        let e = check_out_dir(&file).unwrap_err();
        assert!(
            e.to_string().starts_with(&format!(
                "{}: exists and is not a directory",
                file.display()
            )),
            "{e}"
        );
        assert_eq!(e.exit_code(), crate::base::error::exit::IO);
        let under = file.join("sub");
        let e = check_out_dir(&under).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: cannot create", under.display())),
            "{e}"
        );
        let dir = tmp.path().join("home");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("notes.txt"), "mine").unwrap();
        // a file named like an output directory is not one
        std::fs::write(dir.join("maps"), "mine").unwrap();
        let e = check_out_dir(&dir).unwrap_err().to_string();
        assert!(e.contains("holds 'maps', which kdmap did not write"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn only_kdmap_s_names_count_as_outputs() {
        assert!(is_output("maps", true) && !is_output("maps", false));
        assert!(is_output("report.json", false) && is_output("report.json.tmp", false));
        assert!(!is_output("report.json", true) && !is_output(".git", true));
        assert!(!is_output("input.xml", false));
    }
}
