//! The crate's one-way layering (`src/lib.rs`), checked on the sources: every `crate::<module>`
//! path in `src/` points to a module of a lower layer, or to an earlier module of the same
//! layer (the L2 stages may not use each other at all), so there is no import cycle; and
//! nothing but `main.rs` names `pipeline`.

use std::path::{Path, PathBuf};

/// The layers of `src/lib.rs`, bottom up, each in its allowed order.
const LAYERS: &[&[&str]] = &[
    &[
        "error",
        "rng",
        "progress",
        "fsio",
        "comm",
        "interrupt",
        "mem",
    ],
    &[
        "config", "report", "scene", "scatter", "image", "camera", "accel", "light", "render",
        "atlas",
    ],
    &["project", "denoise", "direct", "gather", "photon", "solve"],
    &["uniform", "checkpoint", "confidence", "output", "accuracy"],
    &["pipeline"],
];
/// The stage layer: its modules are independent of each other.
const STAGES: usize = 2;

fn rank(module: &str) -> Option<(usize, usize)> {
    LAYERS
        .iter()
        .enumerate()
        .find_map(|(l, mods)| mods.iter().position(|m| *m == module).map(|i| (l, i)))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The modules a source text names as `crate::m` or inside `crate::{a, b::c}`, comments
/// removed.
fn crate_paths(text: &str) -> Vec<String> {
    let code: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_lowercase() || *c == '_')
            .collect()
    };
    let mut out = Vec::new();
    for (i, _) in code.match_indices("crate::") {
        let rest = &code[i + 7..];
        if let Some(group) = rest.strip_prefix('{') {
            let group = &group[..group.find('}').unwrap_or(group.len())];
            for item in group.split(',') {
                out.push(ident(item.trim()));
            }
        } else {
            out.push(ident(rest));
        }
    }
    out.retain(|m| !m.is_empty());
    out
}

#[test]
fn no_module_imports_upward_or_in_a_cycle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut bad = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let me = top.trim_end_matches(".rs").to_string();
        if me == "main" || me == "lib" {
            continue;
        }
        let (ml, mi) = rank(&me).unwrap_or_else(|| panic!("{me} is in no layer of lib.rs"));
        for dep in crate_paths(&std::fs::read_to_string(f).unwrap()) {
            let Some((dl, di)) = rank(&dep) else { continue };
            let ok = dep == me || dl < ml || (dl == ml && di < mi && ml != STAGES);
            if !ok {
                bad.push(format!("{}: {me} -> {dep}", rel.display()));
            }
        }
    }
    bad.sort();
    bad.dedup();
    assert!(
        bad.is_empty(),
        "imports against the layering:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_checker_sees_grouped_and_plain_paths_but_not_comments() {
    let text = "use crate::{atlas::Prepared, error::Error};\n// crate::pipeline\nlet x = crate::photon::f();";
    assert_eq!(crate_paths(text), ["atlas", "error", "photon"]);
}
