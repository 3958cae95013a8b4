//! Every run-config key with its unit, meaning and default, in one table: `kdmap config
//! --defaults` prints it as an annotated TOML file and `kdmap config --markdown` as the
//! reference page `docs/config.md`, so neither can drift from the code (tests parse the TOML
//! back to the defaults and check that the table covers every key serde accepts).

use super::{Config, Density, Exposure, Method, Response, UpdateRule};
use std::fmt::Write as _;

/// One key of a run config.
pub struct Key {
    /// Its `[section]`, "" for the top level.
    pub section: &'static str,
    pub name: &'static str,
    /// What its value is measured in, or its type.
    pub unit: &'static str,
    pub doc: &'static str,
    /// The default as a TOML value (from [`Config::for_scene`]).
    pub default: fn(&Config) -> String,
    /// Printed commented out: an alternative to another key, not set by default.
    pub commented: bool,
}

/// A TOML float (`1.0`, not `1`), as short as its type prints it (`1.8`, not
/// `1.7999999523162842`).
fn float(v: impl std::fmt::Debug) -> String {
    format!("{v:?}")
}

fn quoted(s: &str) -> String {
    format!("\"{s}\"")
}

const fn key(
    section: &'static str,
    name: &'static str,
    unit: &'static str,
    doc: &'static str,
    default: fn(&Config) -> String,
) -> Key {
    Key {
        section,
        name,
        unit,
        doc,
        default,
        commented: false,
    }
}

/// Every key a run config accepts (besides the sensor ids of `[views]` and `[shapes.<id>]`,
/// the user's own names), in the order of the default file.
pub const KEYS: &[Key] = &[
    key(
        "",
        "scene",
        "path",
        "The scene: Mitsuba 3 XML or glTF 2.0 (`.gltf`, `.glb`), \
        relative to this file. Required.",
        |_| quoted("scene.xml"),
    ),
    key(
        "",
        "preset",
        "name",
        "The settings the other keys start from: \"default\", \"fast\" \
        (a quick look) or \"paper\" (the published method).",
        |_| quoted("default"),
    ),
    key(
        "views",
        "exposure",
        "\"estimate\" or \"known\"",
        "Each photo's gain (exposure and white balance, per channel): estimated against the \
         other photos and the known lights, or known (the photos are in scene radiance units). \
         A view's table may pin its gain: [views.<id>] exposure = 1.0 (or [r, g, b]).",
        |c| match c.exposure {
            Exposure::Known => quoted("known"),
            Exposure::Estimate => quoted("estimate"),
        },
    ),
    key(
        "views",
        "refine_pose",
        "bool",
        "Refine each camera's pose against the photos before the final projection (at most 2 \
         degrees and 2% of its distance).",
        |c| c.refine_pose.to_string(),
    ),
    key(
        "views",
        "response",
        "\"srgb\", \"linear\", a gamma, or 256 values",
        "How 8-bit photos (PNG, JPEG) become linear: the sRGB curve, linear codes, \
         (code/255)^gamma, or the linear value of each code.",
        |c| match &c.response {
            Response::Srgb => quoted("srgb"),
            Response::Linear => quoted("linear"),
            Response::Gamma(g) => float(g),
            Response::Table(t) => format!("{t:?}"),
        },
    ),
    Key {
        commented: true,
        ..key(
            "views",
            "colmap",
            "path",
            "A COLMAP sparse model (cameras.txt + images.txt, or the .bin pair) standing for \
             the scene's sensors, photos by the names it gives.",
            |_| quoted("sparse/0"),
        )
    },
    Key {
        commented: true,
        ..key(
            "views",
            "to_world",
            "4x4 rows",
            "The similarity from the COLMAP model's frame to the scene's (identity if absent).",
            |_| "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]".into(),
        )
    },
    key(
        "atlas",
        "texels_per_unit",
        "texels per scene unit, or \"auto\"",
        "Texel density: \
        \"auto\" gives each shape the density of the finest pixel footprint any photo gives \
        it, within max_texels and max_texture_size.",
        |c| match c.atlas.texels_per_unit {
            Density::Auto => quoted("auto"),
            Density::PerUnit(d) => float(d),
        },
    ),
    key(
        "atlas",
        "max_texels",
        "texels",
        "With \"auto\" density, at most this many surface \
        texels in all (0 = twice the photos' pixels, at most 1048576).",
        |c| c.atlas.max_texels.to_string(),
    ),
    key(
        "atlas",
        "padding",
        "texels",
        "Empty texels between charts, room for dilation so \
        filtered lookups never read another chart.",
        |c| c.atlas.padding.to_string(),
    ),
    key(
        "atlas",
        "use_mesh_uvs",
        "bool",
        "Keep the meshes' own UVs instead of unwrapping \
        (overlapping UVs are refused).",
        |c| c.atlas.use_mesh_uvs.to_string(),
    ),
    key(
        "atlas",
        "tile_size",
        "texels",
        "Tiles are tile_size x tile_size texels: the unit \
        of memory mapping, parallel work and checkpoints (1..=1024).",
        |c| c.atlas.tile_size.to_string(),
    ),
    key(
        "atlas",
        "max_texture_size",
        "texels",
        "Largest texture side; a shape needing more \
        is refused, never truncated (1..=65536).",
        |c| c.atlas.max_texture_size.to_string(),
    ),
    key(
        "projection",
        "refine_passes",
        "passes",
        "Iterative back-projection passes after \
        the weighted mean, at most (see refine_settle): each re-renders every view and \
        back-projects the residual (0..=64, 0 = off).",
        |c| c.refine_passes.to_string(),
    ),
    key(
        "projection",
        "fine_geometry",
        "bool",
        "Texels no clean (planar) pixel sees are read from pixels that see one surface of \
        their shape (weight x0.1), else from the pixel their center falls in when visible \
        (x0.01): for scenes of small, bevelled or curved parts, where clean pixels are few.",
        |c| c.fine_geometry.to_string(),
    ),
    key(
        "projection",
        "refine_step",
        "factor",
        "Step of the passes after the first (the \
        first takes 1); they converge below 2.",
        |c| float(c.refine_step),
    ),
    key(
        "projection",
        "refine_gate",
        "share",
        "In gated passes a texel keeps its value when \
        under this share of its views' residual is signal (0 = no gate, < 1).",
        |c| float(c.refine_gate),
    ),
    key(
        "projection",
        "refine_gated_from",
        "pass",
        "The first gated pass, from 0 (1 suits \
        scenes of uniform surfaces).",
        |c| c.refine_gated_from.to_string(),
    ),
    key(
        "projection",
        "refine_settle",
        "share",
        "Once a gated pass changed fewer than \
        this share of its texels by more than 1%, the next pass is the last (0 = every pass, \
        < 1).",
        |c| float(c.refine_settle),
    ),
    key(
        "projection",
        "denoise_radius",
        "texels",
        "Radius of the edge-preserving (sigma) \
        filter of the projected luminance (0..=16, 0 = off).",
        |c| c.denoise_radius.to_string(),
    ),
    key(
        "projection",
        "denoise_z",
        "standard errors",
        "Texels within this many standard \
        errors of each other are averaged by that filter.",
        |c| float(c.denoise_z),
    ),
    key(
        "projection",
        "tv_weight",
        "x the photos' relative noise",
        "Total-variation prior \
        after each pass (0..=2, 0 = off; 0.1 suits scenes of uniform surfaces).",
        |c| float(c.tv_weight),
    ),
    key(
        "projection",
        "noise_probe",
        "bool",
        "Measure the photos' noise through the whole \
        projection by projecting them again with added noise (the standard errors of K_d).",
        |c| c.noise_probe.to_string(),
    ),
    key(
        "direct",
        "area_samples",
        "rays",
        "First-pass interior shadow rays per \
        area-emitter triangle (the perimeter is searched too).",
        |c| c.area_samples.to_string(),
    ),
    key(
        "direct",
        "env_samples",
        "sample pairs per texel",
        "Importance-sampled shadow-ray \
        pairs per texel under an environment light (1..=65536).",
        |c| c.env_samples.to_string(),
    ),
    key(
        "gather",
        "rays",
        "rays per gather point",
        "Cosine-weighted rays per gather point \
        (method \"gather\"; rounded up to a square).",
        |c| c.gather_rays.to_string(),
    ),
    key(
        "gather",
        "spacing",
        "scene units",
        "Distance between gather points (0 = \
        automatic: the scene's radius / 32, at most a shape's radius / 16).",
        |c| float(c.gather_spacing),
    ),
    key(
        "photons",
        "per_texel",
        "photons per covered texel",
        "Light paths per iteration \
        and covered texel (method \"photons\"), so E_i's noise per texel does not grow with \
        the atlas.",
        |c| float(c.photons_per_texel.unwrap_or(0.0)),
    ),
    Key {
        commented: true,
        ..key(
            "photons",
            "per_iteration",
            "photons",
            "Or a fixed number of light paths per \
            iteration (as --photons); not together with per_texel.",
            |c| c.photons.to_string(),
        )
    },
    key(
        "photons",
        "batch_size",
        "photons",
        "Photons per batch: the unit of parallel work, \
        determinism and mid-pass checkpoints.",
        |c| c.batch_size.to_string(),
    ),
    key(
        "photons",
        "max_depth",
        "bounces",
        "Longest light path (Russian roulette usually \
        ends paths earlier).",
        |c| c.max_depth.to_string(),
    ),
    key(
        "photons",
        "smoothing_radius",
        "texels",
        "Box filter of the traced E_i within \
        charts (0 = off).",
        |c| c.smoothing_radius.to_string(),
    ),
    key(
        "solver",
        "method",
        "name",
        "How E_i is estimated: \"gather\" (from the observed \
        radiance) or \"photons\" (the paper's light tracing).",
        |c| match c.method {
            Method::Gather => quoted("gather"),
            Method::Photons => quoted("photons"),
        },
    ),
    key(
        "solver",
        "iterations",
        "iterations",
        "At most this many E_i estimates (default 3 \
        with gather, 6 with photons).",
        |c| c.iterations.to_string(),
    ),
    key(
        "solver",
        "tolerance",
        "fraction",
        "Stop when the RMS relative error over observed \
        texels is below this.",
        |c| float(c.tolerance),
    ),
    key(
        "solver",
        "alpha0",
        "factor",
        "Step of the paper's update, alpha_n = alpha0 / (1 + \
        n) (update = \"paper\").",
        |c| float(c.alpha0),
    ),
    key(
        "solver",
        "update",
        "name",
        "How the photon method updates E_i: \"relaxed\", \
        \"secant\", \"paper\" (eqs. 8-9) or \"fixed_point\"; the gather takes its estimate \
        as it is.",
        |c| match c.update {
            UpdateRule::Paper => quoted("paper"),
            UpdateRule::FixedPoint => quoted("fixed_point"),
            UpdateRule::Relaxed => quoted("relaxed"),
            UpdateRule::Secant => quoted("secant"),
        },
    ),
    key(
        "solver",
        "relaxation",
        "share",
        "beta of the relaxed update, E_i += beta (E_i \
        traced - E_i), in (0, 1].",
        |c| float(c.relaxation),
    ),
    key(
        "solver",
        "initial_indirect_share",
        "share of E_d",
        "The first E_i, before any \
        estimate (step 4 of the method).",
        |c| float(c.initial_indirect_share),
    ),
    key(
        "output",
        "uv_fold",
        "\"auto\" or \"off\"",
        "A shape whose UVs tile its texture \
        (4 repeats or more) gets its albedo folded into those UVs for scene.xml, where the \
        atlas follows them.",
        |c| quoted(if c.uv_fold { "auto" } else { "off" }),
    ),
    key(
        "output",
        "uniform_radius",
        "texels",
        "A shape of one colour has its final K_d \
        averaged over this radius (0..=32, 0 = off).",
        |c| c.uniform_radius.to_string(),
    ),
    key(
        "output",
        "uniform_tolerance",
        "share of K_d",
        "... over the neighbours within \
        this share of a texel's K_d (larger steps, a stain, are kept).",
        |c| float(c.uniform_tolerance),
    ),
    key(
        "units",
        "photometric_scale",
        "scene units per photometric unit",
        "glTF scenes: \
        lights in candela and lux and emission in nits are multiplied by this at load.",
        |c| float(c.photometric_scale),
    ),
    key(
        "run",
        "seed",
        "integer",
        "Seed of every random number.",
        |c| c.seed.to_string(),
    ),
    key(
        "run",
        "threads",
        "threads",
        "Worker threads, 0 = all cores; never changes the \
        result.",
        |c| c.threads.to_string(),
    ),
    key(
        "run",
        "checkpoint_every_batches",
        "batches",
        "Photon method: at most one mid-pass \
        checkpoint per this many batches.",
        |c| c.checkpoint_every_batches.to_string(),
    ),
    key(
        "run",
        "checkpoint_every_seconds",
        "seconds",
        "Checkpoints besides the one after \
        direct light and the last: at most this often, and less often when writing them would \
        take over 5% of the run or three would take over half the free disk (0 = at every \
        chance).",
        |c| float(c.checkpoint_every_seconds),
    ),
    key(
        "run",
        "memory_budget_mib",
        "MiB",
        "Working set of memory-mapped tiles and \
        texture buffers (at least 16).",
        |c| c.memory_budget_mib.to_string(),
    ),
    key(
        "run",
        "min_observed_share",
        "share",
        "A run whose photos observe under this share of the covered texels, or whose textures \
        are more than the rest fill, ends with a warning (with --strict, exit code 3); 0 = never.",
        |c| float(c.min_observed_share),
    ),
    key(
        "run",
        "unobserved_share",
        "share",
        "Share of the samples a texel no photo observed gets (the direct light's dense \
        samples, gather rays of points no observed texel reads): its K_d is the fill and its \
        light only feeds what it passes on (above 0, at most 1).",
        |c| c.unobserved_share.to_string(),
    ),
];

/// The sections in file order.
fn sections() -> Vec<&'static str> {
    let mut out: Vec<&str> = Vec::new();
    for k in KEYS {
        if !out.contains(&k.section) {
            out.push(k.section);
        }
    }
    out
}

/// Wraps `text` into lines of at most `width` characters, each starting with `prefix`.
fn wrap(text: &str, prefix: &str, width: usize) -> String {
    let mut out = String::new();
    let mut line = String::from(prefix);
    for word in text.split_whitespace() {
        if line.len() > prefix.len() && line.len() + 1 + word.len() > width {
            out.push_str(line.trim_end());
            out.push('\n');
            line = String::from(prefix);
        }
        if line.len() > prefix.len() {
            line.push(' ');
        }
        line.push_str(word);
    }
    out.push_str(&line);
    out.push('\n');
    out
}

/// The annotated run config holding every default.
pub fn default_toml() -> String {
    let d = Config::for_scene("scene.xml".into());
    let mut out = String::from(
        "# kdmap run config: every key with its default (`kdmap config --defaults`).\n\
         # Paths are relative to this file; every key but `scene` is optional; unknown keys\n\
         # are errors; command-line flags override what is written here.\n",
    );
    for s in sections() {
        if !s.is_empty() {
            let _ = write!(out, "\n[{s}]\n");
        }
        for k in KEYS.iter().filter(|k| k.section == s) {
            out.push('\n');
            out.push_str(&wrap(&format!("{} [{}]", k.doc, k.unit), "# ", 92));
            let hash = if k.commented { "# " } else { "" };
            let _ = writeln!(out, "{hash}{} = {}", k.name, (k.default)(&d));
        }
    }
    out.push_str(
        "\n# [views] also maps a sensor id to its photo (default <scene dir>/images/<id>.exr,\n\
         # .png or .jpg), or to a table with its photo and a pinned gain:\n\
         # cam_0 = \"photos/cam_0.exr\"\n\
         # cam_1 = { photo = \"photos/cam_1.jpg\", exposure = 1.0 }\n\
         \n# [shapes.<id>]: a shape whose diffuse reflectance is known: kept, not reconstructed\n\
         # reconstruct = false\n# reflectance = [0.725, 0.71, 0.68]   # or one number, in [0, 1]\n\
         # (a plastic's base is reconstructed by default; reconstruct = false alone keeps the\n\
         # base its scene states)\n",
    );
    out
}

/// The reference page `docs/config.md`.
pub fn markdown() -> String {
    let d = Config::for_scene("scene.xml".into());
    let mut out = String::from(
        "# Run-config reference\n\n\
         Generated by `kdmap config --markdown` from the table in `src/config/keys.rs`; do \
         not edit by hand\n(a test fails when this page and the code differ). \
         `kdmap config --defaults` prints the same keys as a\nTOML file to start from. \
         Presets (`preset = \"fast\"`, `--preset paper`) change some defaults; see\n\
         [guide.md](guide.md).\n",
    );
    for s in sections() {
        let title = if s.is_empty() {
            "Top level".to_string()
        } else {
            format!("`[{s}]`")
        };
        let _ = write!(
            out,
            "\n## {title}\n\n| key | default | unit | meaning |\n|---|---|---|---|\n"
        );
        for k in KEYS.iter().filter(|k| k.section == s) {
            let default = if k.commented {
                "(not set)".to_string()
            } else {
                format!("`{}`", (k.default)(&d))
            };
            let _ = writeln!(out, "| `{}` | {default} | {} | {} |", k.name, k.unit, k.doc);
        }
    }
    out.push_str(
        "\n## Sensor ids in `[views]`, and `[shapes.<id>]`\n\n\
         Besides the settings above, `[views]` maps a sensor id to its photo (a path relative \
         to the config:\n`cam_0 = \"photos/cam_0.exr\"`), or to a table with its photo and a \
         pinned gain (`cam_1 = { photo =\n\"photos/cam_1.jpg\", exposure = 1.0 }`). \
         Without photo entries every sensor with a file\n`<scene dir>/images/<sensor \
         id>.exr` (or `.png`, `.jpg`) is used. `[shapes.<id>]` with `reconstruct =\nfalse` \
         and `reflectance` (one number or `[r, g, b]`, linear, in [0, 1]) marks a shape whose \
         albedo\nis known: it keeps that value and takes part in the light transport. A coated \
         shape (`plastic`,\n`roughplastic`, a `principled` with `metallic = 0` and `spec_trans = 0`) \
         has its diffuse base\nreconstructed under its known coat; `reconstruct = false` without a \
         `reflectance` keeps the base\nits scene states (`reconstruct = true` is the default).\n",
    );
    out
}
