//! The crate's one-way layering (`src/lib.rs`), checked on the sources at every depth: each
//! folder lists its modules in layers, bottom up, and a module may use only modules of lower
//! layers of its folder, or earlier ones of its own layer (none of its own layer where the
//! layer is marked independent). A path is resolved to the module that defines what it names,
//! through the `pub use` re-exports of each folder's `mod.rs`, so a sibling reached through
//! the folder's interface still counts as that sibling. A module may use its ancestors' own
//! items (a folder's shared types) and its own descendants. So there is no import cycle, and
//! nothing but `main.rs` names `pipeline`, the top layer. Test code (inline `mod tests`,
//! `tests.rs`, `testing.rs`) may reach any fixture and is not checked.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A layer of a folder: its modules and how they may use each other.
type Layer = (&'static [&'static str], Order);

/// Each folder's modules in layers, bottom up, and whether modules of one layer may use each
/// other (in the order listed) or are independent.
const FOLDERS: &[(&str, &[Layer])] = &[
    (
        "",
        &[
            (&["base"], Listed),
            (
                &["config", "report", "scene", "image", "physics", "atlas"],
                Listed,
            ),
            (&["stages"], Listed),
            (&["checkpoint", "output", "accuracy"], Listed),
            (&["pipeline"], Listed),
        ],
    ),
    ("report", &[(&["summary"], Listed)]),
    (
        "config",
        &[
            (&["views"], Listed),
            (&["raw", "validate", "keys"], Independent),
        ],
    ),
    (
        "base",
        &[(
            &[
                "error",
                "rng",
                "progress",
                "fsio",
                "comm",
                "interrupt",
                "mem",
            ],
            Listed,
        )],
    ),
    (
        "scene",
        &[
            (
                &["material", "filter", "mesh", "envmap", "lens", "photos"],
                Listed,
            ),
            (&["mitsuba", "gltf", "colmap"], Independent),
            (&["truth"], Listed),
        ],
    ),
    (
        "scene::gltf",
        &[(&["accessor", "primitive", "sensor", "lights"], Listed)],
    ),
    ("scene::mitsuba", &[(&["bsdf", "sensor"], Independent)]),
    ("scene::colmap", &[(&["text", "binary"], Independent)]),
    (
        "physics",
        &[(
            &[
                "accel",
                "camera",
                "bsdf_sampling",
                "coat",
                "light",
                "render",
                "film_filter",
            ],
            Listed,
        )],
    ),
    ("physics::light", &[(&["sampler", "area", "env"], Listed)]),
    ("physics::light::area", &[(&["piece"], Listed)]),
    (
        "atlas",
        &[
            (&["store"], Listed),
            (&["texture"], Listed),
            (&["uv"], Listed),
            (&["sigma"], Listed),
            (&["context"], Listed),
            (&["testing"], Listed),
        ],
    ),
    (
        "atlas::store",
        &[(&["layout", "tiles", "cache", "check"], Listed)],
    ),
    ("atlas::texture", &[(&["dilate", "whole", "slot"], Listed)]),
    (
        "atlas::uv",
        &[(
            &[
                "shape_atlas",
                "density",
                "orient",
                "texels",
                "unwrap",
                "charts",
            ],
            Listed,
        )],
    ),
    (
        "atlas::context",
        &[(&["prepare", "geometry", "hits"], Listed)],
    ),
    (
        "stages",
        &[
            (
                &["project", "denoise", "direct", "indirect", "solve"],
                Independent,
            ),
            (&["one_colour", "confidence"], Independent),
        ],
    ),
    (
        "stages::project",
        &[(
            &[
                "one_surface",
                "view",
                "coat",
                "keep",
                "lookups",
                "visible",
                "exposure",
                "window_median",
                "noise",
                "shrinkage",
                "pass_texel",
                "total_variation",
                "noise_probe",
                "diagnose",
                "refine",
                "edges",
                "pose",
            ],
            Listed,
        )],
    ),
    (
        "stages::direct",
        &[(&["coat", "sampling"], Independent), (&["smooth"], Listed)],
    ),
    ("stages::indirect", &[(&["gather", "photon"], Independent)]),
    ("stages::indirect::gather", &[(&["budget"], Independent)]),
    (
        "stages::indirect::photon",
        &[(&["smooth", "trace"], Independent)],
    ),
    (
        "output",
        &[
            (&["typeface", "bsdf_xml", "obj", "out_dir"], Independent),
            (
                &[
                    "plot",
                    "page",
                    "convergence",
                    "maps",
                    "renders",
                    "scene_glb",
                    "scene_xml",
                    "uv_fold",
                ],
                Listed,
            ),
        ],
    ),
    (
        "output::page",
        &[
            (&["html", "facts", "assets"], Independent),
            (
                &["svg", "summary", "views", "shapes", "figures", "tables"],
                Listed,
            ),
        ],
    ),
];

#[derive(Clone, Copy, PartialEq)]
enum Order {
    /// A module may use the ones listed before it in its layer.
    Listed,
    /// Modules of the layer may not use each other.
    Independent,
}
use Order::{Independent, Listed};

/// Where `child` of `folder` sits: (layer, position, order of the layer).
fn rank(folder: &str, child: &str) -> Option<(usize, usize, Order)> {
    let (_, layers) = FOLDERS.iter().find(|(f, _)| *f == folder)?;
    layers.iter().enumerate().find_map(|(l, (mods, order))| {
        mods.iter()
            .position(|m| *m == child)
            .map(|i| (l, i, *order))
    })
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

/// The module path of a source file: `a/b.rs` and `a/b/mod.rs` are `a::b`.
fn module_of(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" {
        parts.push(stem.to_string());
    }
    parts
}

/// Source text without comments (line comments only: the crate has no block comments).
fn code_of(text: &str) -> String {
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

fn ident(s: &str) -> String {
    s.chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect()
}

/// The paths the non-test code of a source names, as segments after `crate` (`crate::a::b::C`)
/// or resolved from `super::` (the file module's parent), one path per item of a group
/// `{a, b::c}`.
fn named_paths(text: &str, module: &[String]) -> Vec<Vec<String>> {
    let code = code_of(text);
    let code = &code[..code.find("mod tests {").unwrap_or(code.len())];
    let mut out = Vec::new();
    for (kind, prefix) in [("crate", "crate::"), ("super", "super::")] {
        for (i, _) in code.match_indices(prefix) {
            if i > 0 && {
                let c = code.as_bytes()[i - 1];
                c.is_ascii_alphanumeric() || c == b'_' || c == b':'
            } {
                continue;
            }
            let mut base: Vec<String> = if kind == "crate" {
                Vec::new()
            } else {
                module[..module.len().saturating_sub(1)].to_vec()
            };
            let mut rest = &code[i + prefix.len()..];
            while let Some(r) = rest.strip_prefix("super::") {
                base.pop();
                rest = r;
            }
            let mut heads = Vec::new();
            let mut segs = base.clone();
            loop {
                if let Some(group) = rest.strip_prefix('{') {
                    let group = &group[..group.find('}').unwrap_or(group.len())];
                    for item in group.split(',') {
                        let mut p = segs.clone();
                        p.extend(item.trim().split("::").map(ident).filter(|s| !s.is_empty()));
                        heads.push(p);
                    }
                    break;
                }
                let id = ident(rest);
                if id.is_empty() {
                    heads.push(segs.clone());
                    break;
                }
                segs.push(id.clone());
                rest = &rest[id.len()..];
                match rest.strip_prefix("::") {
                    Some(r) => rest = r,
                    None => {
                        heads.push(segs.clone());
                        break;
                    }
                }
            }
            out.extend(heads.into_iter().filter(|p| !p.is_empty() && p != &base));
        }
    }
    out
}

/// The crate's modules and each folder module's re-exports (`pub use child::{A, B}`): name ->
/// the child that defines it.
struct Tree {
    modules: Vec<Vec<String>>,
    reexports: HashMap<(Vec<String>, String), String>,
}

impl Tree {
    fn new(src: &Path, files: &[PathBuf]) -> Tree {
        let mut modules = Vec::new();
        let mut reexports = HashMap::new();
        for f in files {
            let module = module_of(f.strip_prefix(src).unwrap());
            let code = code_of(&std::fs::read_to_string(f).unwrap());
            for stmt in code.split(';') {
                let s = stmt.trim();
                let Some(body) = ["pub use ", "pub(crate) use "]
                    .iter()
                    .find_map(|p| s.strip_prefix(p))
                else {
                    continue;
                };
                let (child, names) = body.split_once("::").unwrap_or((body, ""));
                let names = names.trim_start_matches('{').trim_end_matches('}');
                for name in names.split(',') {
                    let name = ident(name.trim().split("::").last().unwrap_or(""));
                    if !name.is_empty() {
                        reexports.insert((module.clone(), name), ident(child.trim()));
                    }
                }
            }
            modules.push(module);
        }
        Tree { modules, reexports }
    }

    fn is_module(&self, p: &[String]) -> bool {
        self.modules.iter().any(|m| m == p)
    }

    /// The module that defines what `path` names: its longest module prefix, followed
    /// through re-exports (of re-exports) into the child that defines the next name.
    fn resolve(&self, path: &[String]) -> Option<Vec<String>> {
        let n = (1..=path.len())
            .rev()
            .find(|&n| self.is_module(&path[..n]))?;
        let mut m = path[..n].to_vec();
        while n < path.len() {
            let Some(child) = self.reexports.get(&(m.clone(), path[n].clone())) else {
                break;
            };
            if child == "self" || child == "crate" || child == "super" {
                break;
            }
            let mut c = m.clone();
            c.push(child.clone());
            if !self.is_module(&c) {
                break;
            }
            m = c;
        }
        Some(m)
    }
}

/// Why `from` may not use `to`, if it may not.
fn violation(from: &[String], to: &[String]) -> Option<String> {
    let common = from.iter().zip(to).take_while(|(a, b)| a == b).count();
    if common == from.len() || common == to.len() {
        return None; // an ancestor's own items, or a descendant
    }
    let folder = from[..common].join("::");
    let (a, d) = (&from[common], &to[common]);
    let Some((la, ia, order)) = rank(&folder, a) else {
        return Some(format!("{a} is in no layer of folder '{folder}'"));
    };
    let Some((ld, id, _)) = rank(&folder, d) else {
        return Some(format!("{d} is in no layer of folder '{folder}'"));
    };
    let ok = ld < la || (ld == la && id < ia && order == Listed);
    (!ok).then(|| format!("{} -> {}", from.join("::"), to.join("::")))
}

#[test]
fn no_module_imports_upward_or_in_a_cycle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.retain(|f| !f.ends_with("main.rs"));
    let tree = Tree::new(&src, &files);
    let mut bad = Vec::new();
    let test_code = |f: &Path| f.ends_with("tests.rs") || f.ends_with("testing.rs");
    for f in files.iter().filter(|f| !test_code(f)) {
        let module = module_of(f.strip_prefix(&src).unwrap());
        for path in named_paths(&std::fs::read_to_string(f).unwrap(), &module) {
            let Some(to) = tree.resolve(&path) else {
                continue;
            };
            if let Some(why) = violation(&module, &to) {
                bad.push(format!(
                    "{}: {why}",
                    f.strip_prefix(&src).unwrap().display()
                ));
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
fn the_checker_sees_grouped_super_and_plain_paths_but_not_comments() {
    let m = |s: &str| s.split("::").map(String::from).collect::<Vec<_>>();
    let text = "use crate::{atlas::RunContext, base::error::Error};\n// crate::pipeline\n\
                use super::tiles::TileStore;\nlet x = crate::stages::indirect::photon::f();";
    assert_eq!(
        named_paths(text, &m("atlas::store::check")),
        [
            m("atlas::RunContext"),
            m("base::error::Error"),
            m("stages::indirect::photon::f"),
            m("atlas::store::tiles::TileStore"),
        ]
    );
}

#[test]
fn the_checker_refuses_a_cycle_between_siblings_and_an_upward_path() {
    let m = |s: &str| s.split("::").map(String::from).collect::<Vec<_>>();
    // the cycle the atlas once had: unwrap and texels using each other
    assert!(violation(&m("atlas::uv::texels"), &m("atlas::uv::unwrap")).is_some());
    assert!(violation(&m("atlas::uv::unwrap"), &m("atlas::uv::texels")).is_none());
    // a stage using another stage of the independent layer, and anything naming the pipeline
    assert!(violation(&m("stages::solve"), &m("stages::denoise")).is_some());
    assert!(violation(&m("output::maps"), &m("pipeline")).is_some());
    // ancestors' items and lower layers are fine
    assert!(violation(&m("atlas::uv::charts"), &m("atlas")).is_none());
    assert!(violation(&m("stages::one_colour"), &m("stages::denoise")).is_none());
    // a module in no layer is reported, not passed
    assert!(violation(&m("atlas::uv::newcomer"), &m("atlas::uv::texels")).is_some());
}

#[test]
fn re_exports_resolve_to_the_defining_sibling() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let tree = Tree::new(&src, &files);
    let m = |s: &str| s.split("::").map(String::from).collect::<Vec<_>>();
    assert_eq!(
        tree.resolve(&m("atlas::store::TileStore")),
        Some(m("atlas::store::tiles"))
    );
    assert_eq!(
        tree.resolve(&m("atlas::RunContext")),
        Some(m("atlas::context::prepare"))
    );
}

#[test]
fn the_architecture_page_names_every_source_file() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let page = std::fs::read_to_string(root.join("docs/architecture.md")).unwrap();
    let src = root.join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut missing: Vec<String> = files
        .iter()
        .filter(|f| !f.ends_with("tests.rs") && !f.ends_with("testing.rs"))
        .map(|f| f.strip_prefix(&src).unwrap().display().to_string())
        .filter(|rel| !page.contains(&format!("`{rel}`")))
        .collect();
    missing.sort();
    assert!(
        missing.is_empty(),
        "docs/architecture.md does not name: {}",
        missing.join(", ")
    );
}
