//! The run config's parsing, presets, overrides and validation.
use super::*;
use std::path::{Path, PathBuf};

#[test]
fn gather_spacing_follows_the_scene_and_small_shapes_unless_set() {
    let mut c = Config::for_scene("a.xml".into());
    assert_eq!(
        c.gather_spacing_for(32.0, 100.0),
        1.0,
        "a shape as large as the scene"
    );
    assert_eq!(
        c.gather_spacing_for(32.0, 8.0),
        0.5,
        "a small shape: its own sixteenth"
    );
    assert_eq!(c.gather_spacing_for(32.0, 0.0), 1.0, "a degenerate shape");
    c.gather_spacing = 0.25;
    assert_eq!(c.gather_spacing_for(32.0, 8.0), 0.25, "as configured");
}

#[test]
fn toml_overrides_defaults_and_paths_resolve_against_the_file() {
    let text = r#"
            scene = "scenes/a.xml"
            [views]
            cam0 = "photos/c0.exr"
            [atlas]
            texels_per_unit = 32.0
            [solver]
            iterations = 3
            update = "fixed_point"
        "#;
    let c = Config::from_toml(Path::new("/x/y/run.toml"), text).unwrap();
    assert_eq!(c.scene, PathBuf::from("/x/y/scenes/a.xml"));
    assert_eq!(c.views["cam0"], PathBuf::from("/x/y/photos/c0.exr"));
    assert_eq!(c.atlas.texels_per_unit, Density::PerUnit(32.0));
    assert_eq!(c.iterations, 3);
    assert_eq!(c.update, UpdateRule::FixedPoint);
    // untouched settings keep their defaults
    let d = Config::for_scene(PathBuf::new());
    assert_eq!(c.photons, d.photons);
    assert_eq!(c.alpha0, d.alpha0);
}

#[test]
fn texel_density_is_auto_by_default_a_number_or_auto_and_nothing_else() {
    let d = Config::for_scene(PathBuf::new());
    assert_eq!(d.atlas.texels_per_unit, Density::Auto);
    let at = |v: &str| {
        let text = format!("scene = \"a.xml\"\n[atlas]\ntexels_per_unit = {v}\n");
        Config::from_toml(Path::new("run.toml"), &text)
    };
    assert_eq!(
        at("48").unwrap().atlas.texels_per_unit,
        Density::PerUnit(48.0)
    );
    assert_eq!(at("\"auto\"").unwrap().atlas.texels_per_unit, Density::Auto);
    let e = at("\"fine\"").unwrap_err().to_string();
    assert!(e.contains("\"fine\"") && e.contains("auto"), "{e}");
    let text = "scene = \"a.xml\"\n[atlas]\nmax_texels = 5000\n";
    let c = Config::from_toml(Path::new("run.toml"), text).unwrap();
    assert_eq!(c.atlas.max_texels, 5000);
}

/// `[output] uv_fold`: on by default ("auto"), "off" turns it off, anything else is refused
/// with the key and the values it takes.
#[test]
fn uv_fold_is_auto_or_off() {
    let at = |v: &str| {
        let text = format!("scene = \"a.xml\"\n[output]\nuv_fold = {v}\n");
        Config::from_toml(Path::new("run.toml"), &text)
    };
    assert!(Config::for_scene("a.xml".into()).uv_fold);
    assert!(at("\"auto\"").unwrap().uv_fold);
    assert!(!at("\"off\"").unwrap().uv_fold);
    let e = at("\"on\"").unwrap_err().to_string();
    assert!(
        e.contains("output.uv_fold = \"on\"") && e.contains("\"off\""),
        "{e}"
    );
    assert!(at("true").is_err());
}

#[test]
fn unknown_key_is_an_error_naming_file_and_line() {
    let text = "scene = \"a.xml\"\n[atlas]\ntexels_per_unt = 3.0\n";
    let e = Config::from_toml(Path::new("run.toml"), text)
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("run.toml (line 3)"), "{e}");
    assert!(e.contains("texels_per_unt"), "{e}");
    assert!(!e.contains('\n'));
}

#[test]
fn impossible_settings_are_refused() {
    let mut c = Config::for_scene("s.xml".into());
    assert!(c.validate().is_ok());
    c.photons = 0;
    assert!(c.validate().unwrap_err().contains("photons"));
    let mut c = Config::for_scene("s.xml".into());
    c.atlas.texels_per_unit = Density::PerUnit(f32::NAN);
    assert!(c.validate().unwrap_err().contains("texels_per_unit"));
    let mut c = Config::for_scene("s.xml".into());
    c.iterations = 0;
    assert!(c.validate().unwrap_err().contains("iterations"));
    let mut c = Config::for_scene("s.xml".into());
    c.refine_passes = MAX_REFINE_PASSES + 1;
    assert!(c.validate().unwrap_err().contains("refine_passes"));
    for step in [0.0, 2.0, -1.0, f32::NAN] {
        let mut c = Config::for_scene("s.xml".into());
        c.refine_step = step;
        assert!(c.validate().unwrap_err().contains("refine_step"), "{step}");
    }
    for gate in [-0.1, 1.0, f32::NAN] {
        let mut c = Config::for_scene("s.xml".into());
        c.refine_gate = gate;
        assert!(c.validate().unwrap_err().contains("refine_gate"), "{gate}");
    }
    let mut c = Config::for_scene("s.xml".into());
    c.refine_settle = 1.0;
    assert!(c.validate().unwrap_err().contains("refine_settle"));
    c.refine_settle = 0.0;
    c.refine_gated_from = MAX_REFINE_PASSES + 1;
    assert!(c.validate().unwrap_err().contains("refine_gated_from"));
    let mut c = Config::for_scene("s.xml".into());
    c.uniform_radius = MAX_UNIFORM_RADIUS + 1;
    assert!(c.validate().unwrap_err().contains("uniform_radius"));
    for t in [0.0, -0.1, f32::NAN, f32::INFINITY] {
        let mut c = Config::for_scene("s.xml".into());
        c.uniform_tolerance = t;
        assert!(
            c.validate().unwrap_err().contains("uniform_tolerance"),
            "{t}"
        );
    }
    let mut c = Config::for_scene("s.xml".into());
    c.denoise_radius = MAX_DENOISE_RADIUS + 1;
    assert!(c.validate().unwrap_err().contains("denoise_radius"));
    for z in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let mut c = Config::for_scene("s.xml".into());
        c.denoise_z = z;
        assert!(c.validate().unwrap_err().contains("denoise_z"), "{z}");
    }
    for w in [-0.1, MAX_TV_WEIGHT + 0.1, f32::NAN] {
        let mut c = Config::for_scene("s.xml".into());
        c.tv_weight = w;
        assert!(c.validate().unwrap_err().contains("tv_weight"), "{w}");
    }
}

/// `[direct] env_samples` sets the pairs per texel under an environment light; 0 and
/// more than the cap are refused with the key named.
#[test]
fn direct_section_sets_env_samples() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("run.toml");
    std::fs::write(&p, "scene = \"s.xml\"\n[direct]\nenv_samples = 1024\n").unwrap();
    let c = Config::load(&p, &Overrides::default()).unwrap();
    assert_eq!(c.env_samples, 1024);
    assert_eq!(Config::for_scene("s.xml".into()).env_samples, ENV_SAMPLES);
    for bad in [0, MAX_ENV_SAMPLES + 1] {
        let mut c = Config::for_scene("s.xml".into());
        c.env_samples = bad;
        assert!(
            c.validate().unwrap_err().contains("direct.env_samples"),
            "{bad}"
        );
    }
}

#[test]
fn projection_section_sets_refine_passes() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("run.toml");
    std::fs::write(
        &p,
        "scene = \"s.xml\"\n[projection]\nrefine_passes = 1\nrefine_step = 1.25\n\
             refine_gate = 0.5\nrefine_gated_from = 2\nrefine_settle = 0.01\ndenoise_radius = 3\ndenoise_z = 2.5\n\
             tv_weight = 0.2\nnoise_probe = false\n",
    )
    .unwrap();
    let c = Config::load(&p, &Overrides::default()).unwrap();
    assert!(!c.noise_probe);
    assert!(
        Config::for_scene("s.xml".into()).noise_probe,
        "on by default"
    );
    assert_eq!((c.refine_passes, c.refine_step), (1, 1.25));
    assert_eq!((c.refine_gate, c.refine_gated_from), (0.5, 2));
    assert_eq!(c.refine_settle, 0.01);
    assert_eq!((c.denoise_radius, c.denoise_z), (3, 2.5));
    assert_eq!(c.tv_weight, 0.2);
    std::fs::write(&p, "scene = \"s.xml\"\n[projection]\nrefine = 1\n").unwrap();
    let e = Config::load(&p, &Overrides::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("refine"), "{e}");
}

#[test]
fn presets_set_their_values_and_file_keys_win_over_them() {
    let d = Config::for_scene("s.xml".into());
    let f = Config::fast("s.xml".into());
    let budget = |c: &Config| c.with_photon_budget_for(1_000_000).photons;
    assert!(budget(&f) < budget(&d) && f.iterations < d.iterations);
    assert!(f.refine_passes < d.refine_passes && f.validate().is_ok());
    let p = Config::paper("s.xml".into());
    assert_eq!(
        (p.update, p.refine_passes, p.smoothing_radius),
        (UpdateRule::Paper, 0, 0)
    );
    let text = "scene = \"s.xml\"\npreset = \"fast\"\n[photons]\nper_iteration = 7\n";
    let c = Config::from_toml(Path::new("r.toml"), text).unwrap();
    assert_eq!((c.photons, c.iterations), (7, f.iterations));
    // a preset flag replaces the file's preset, the file's keys still apply
    let c = Config::from_toml_with(Path::new("r.toml"), text, Some(Preset::Paper)).unwrap();
    assert_eq!((c.photons, c.update), (7, UpdateRule::Paper));
    let e = Config::from_toml(
        Path::new("r.toml"),
        "scene = \"s.xml\"\npreset = \"turbo\"\n",
    )
    .unwrap_err();
    assert!(
        e.to_string().starts_with("r.toml: preset = \"turbo\""),
        "{e}"
    );
    assert_eq!(e.exit_code(), crate::base::error::exit::CONFIG);
}

#[test]
fn photon_budgets_per_texel_resolve_with_the_atlas_and_fixed_counts_win() {
    let d = Config::for_scene("s.xml".into());
    // the default: PHOTONS_PER_TEXEL per covered texel, at least one batch
    assert_eq!(d.with_photon_budget_for(200_000).photons, 20_000_000);
    assert_eq!(d.with_photon_budget_for(10).photons, d.batch_size as u64);
    let r = Path::new("r.toml");
    let c = Config::from_toml(r, "scene = \"s.xml\"\n[photons]\nper_texel = 2.5\n").unwrap();
    assert_eq!(c.with_photon_budget_for(1_000_000).photons, 2_500_000);
    // a fixed count is kept whatever the atlas
    let c = Config::from_toml(r, "scene = \"s.xml\"\n[photons]\nper_iteration = 9\n").unwrap();
    assert_eq!(
        (
            c.photons_per_texel,
            c.with_photon_budget_for(5_000_000).photons
        ),
        (None, 9)
    );
    let both = "scene = \"s.xml\"\n[photons]\nper_iteration = 9\nper_texel = 3\n";
    let e = Config::from_toml(r, both).unwrap_err();
    assert!(e.to_string().contains("per_texel"), "{e}");
    for bad in ["0", "-1", "nan", "1e9"] {
        let t = format!("scene = \"s.xml\"\n[photons]\nper_texel = {bad}\n");
        let e = Config::from_toml(r, &t).and_then(|c| {
            c.validate().map_err(Error::config)?;
            Ok(c)
        });
        assert!(e.is_err(), "per_texel = {bad} accepted");
    }
    let mut c = d.clone();
    c.set_photons(42);
    assert_eq!(c.with_photon_budget_for(1 << 30).photons, 42);
}

#[test]
fn flags_override_config() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("run.toml");
    std::fs::write(&p, "scene = \"s.xml\"\n[photons]\nper_iteration = 5\n").unwrap();
    let c = Config::load(&p, &Overrides::default()).unwrap();
    assert_eq!(c.photons, 5);
    let ov = Overrides {
        photons: Some(7),
        iterations: Some(2),
        seed: Some(9),
        threads: Some(1),
        ..Default::default()
    };
    let c = Config::load(&p, &ov).unwrap();
    assert_eq!((c.photons, c.iterations, c.seed, c.threads), (7, 2, 9, 1));
    let ov = Overrides {
        photons: Some(0),
        ..Default::default()
    };
    let e = Config::load(&p, &ov).unwrap_err();
    assert_eq!(e.exit_code(), crate::base::error::exit::CONFIG);
    let e = e.to_string();
    assert!(e.contains("run.toml") && e.contains("photons"), "{e}");
}

/// The documented example in `configs/` parses and validates.
#[test]
fn shipped_example_config_is_valid() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/example.toml");
    let c = Config::load(&p, &Overrides::default()).unwrap();
    assert_eq!(c.views.len(), 3);
    assert!(c.scene.ends_with("tests/fixtures/cbox/input.xml"));
    assert!(c.scene.is_file(), "{}", c.scene.display());
}

/// The 100M-texel run's config (its scene is generated into the cache on demand) parses,
/// validates and asks for its documented density (820 texels per unit).
#[test]
fn room_100m_config_is_valid() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/room-100m.toml");
    let c = Config::load(&p, &Overrides::default()).unwrap();
    assert!(c.scene.ends_with("cache/scenes/room-pointspot/input.xml"));
    assert_eq!(c.atlas.texels_per_unit.per_unit(), Some(820.0));
    assert_eq!(c.memory_budget_mib, 1024);
}

/// The keys serde accepts in `section` ("" = the top level), read from its refusal of an
/// unknown key ("unknown field `x`, expected one of `a`, `b`").
fn accepted_keys(section: &str) -> Vec<String> {
    let text = if section.is_empty() {
        "probe_ = 1\n".to_string()
    } else {
        format!("scene = \"a.xml\"\n[{section}]\nprobe_ = 1\n")
    };
    let e = Config::from_toml(Path::new("run.toml"), &text)
        .unwrap_err()
        .to_string();
    let list = e.split("expected").nth(1).unwrap_or_else(|| panic!("{e}"));
    list.split('`')
        .skip(1)
        .step_by(2)
        .map(String::from)
        .collect()
}

#[test]
fn the_key_table_covers_every_key_serde_accepts() {
    let tables = ["views", "shapes"];
    let views: Vec<&str> = (keys::KEYS.iter())
        .filter(|k| k.section == "views")
        .map(|k| k.name)
        .collect();
    assert_eq!(views, views::SETTINGS);
    let mut sections = accepted_keys("");
    sections.retain(|k| !tables.contains(&k.as_str()));
    let top: Vec<String> = keys::KEYS
        .iter()
        .filter(|k| k.section.is_empty())
        .map(|k| k.name.to_string())
        .collect();
    for s in sections {
        let expected = if top.contains(&s) {
            continue;
        } else {
            accepted_keys(&s)
        };
        let mut documented: Vec<String> = keys::KEYS
            .iter()
            .filter(|k| k.section == s)
            .map(|k| k.name.to_string())
            .collect();
        let mut expected = expected;
        expected.sort();
        documented.sort();
        assert_eq!(documented, expected, "[{s}]");
    }
    assert!(accepted_keys("atlas").contains(&"tile_size".to_string()));
}

#[test]
fn the_default_file_parses_back_to_the_defaults() {
    let text = keys::default_toml();
    let path = Path::new("/x/run.toml");
    let mut c = Config::from_toml(path, &text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    c.source = None;
    assert_eq!(c, Config::for_scene(PathBuf::from("/x/scene.xml")));
    // every key is in it, set or (for alternatives) commented out
    for k in keys::KEYS {
        let line = format!("{}{} = ", if k.commented { "# " } else { "" }, k.name);
        assert!(text.contains(&format!("\n{line}")), "{line}");
    }
    assert!(text.lines().all(|l| l.len() <= 100), "{text}");
}

#[test]
fn docs_config_md_is_the_generated_reference() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/config.md");
    let page = std::fs::read_to_string(&p).unwrap_or_default();
    assert!(
        page == keys::markdown(),
        "docs/config.md differs from the code: run `cargo run --release -- config --markdown > \
         docs/config.md`"
    );
}

#[test]
fn views_hold_photos_pinned_gains_and_the_capture_settings() {
    let text = r#"
        scene = "a.xml"
        [views]
        exposure = "estimate"
        refine_pose = true
        response = 2.2
        colmap = "sparse/0"
        to_world = [[2, 0, 0, 1], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]
        cam0 = "photos/c0.jpg"
        cam1 = { photo = "photos/c1.png", exposure = [1.0, 0.5, 2] }
        [views.cam2]
        exposure = 0.25
    "#;
    let c = Config::from_toml(Path::new("/x/run.toml"), text).unwrap();
    assert_eq!(c.exposure, Exposure::Estimate);
    assert!(c.refine_pose);
    assert_eq!(c.response, Response::Gamma(2.2));
    assert_eq!(c.colmap, Some(PathBuf::from("/x/sparse/0")));
    assert_eq!(c.colmap_to_world.unwrap()[0], [2.0, 0.0, 0.0, 1.0]);
    assert_eq!(c.views.len(), 2);
    assert_eq!(c.views["cam1"], PathBuf::from("/x/photos/c1.png"));
    assert_eq!(c.pinned_gains["cam1"], [1.0, 0.5, 2.0]);
    assert_eq!(c.pinned_gains["cam2"], [0.25; 3]);
    // the defaults: gains estimated (known in the paper's method), poses as given, sRGB
    let d = Config::for_scene("a.xml".into());
    assert_eq!(
        (d.exposure, d.refine_pose, d.response),
        (Exposure::Estimate, false, Response::Srgb)
    );
    assert_eq!(Config::paper("a.xml".into()).exposure, Exposure::Known);
}

#[test]
fn bad_views_entries_are_refused_naming_the_key() {
    let bad = [
        ("exposure = \"auto\"", "views.exposure"),
        ("refine_pose = 1", "views.refine_pose"),
        ("response = \"log\"", "views.response"),
        ("cam0 = 3", "views.cam0"),
        (
            "cam0 = { photo = \"a.exr\", gain = 2 }",
            "unknown key 'gain'",
        ),
        ("cam0 = { exposure = \"x\" }", "views.cam0.exposure"),
        ("to_world = [[1, 0], [0, 1]]", "views.to_world"),
    ];
    for (line, want) in bad {
        let text = format!("scene = \"a.xml\"\n[views]\n{line}\n");
        let e = Config::from_toml(Path::new("run.toml"), &text).unwrap_err();
        assert!(e.to_string().contains(want), "{line}: {e}");
    }
    for line in ["cam0 = { exposure = -1.0 }", "response = 0.0"] {
        let text = format!("scene = \"a.xml\"\n[views]\n{line}\n");
        let c = Config::from_toml(Path::new("run.toml"), &text).unwrap();
        let e = c.validate().unwrap_err();
        assert!(e.contains("views."), "{line}: {e}");
    }
}

#[test]
fn to_world_must_be_a_similarity_of_a_colmap_model() {
    let cfg = |m: &str, colmap: bool| {
        let model = if colmap { "colmap = \"sparse\"\n" } else { "" };
        let text = format!("scene = \"a.xml\"\n[views]\n{model}to_world = {m}\n");
        Config::from_toml(Path::new("run.toml"), &text).unwrap()
    };
    // scale 2, a quarter turn about z, a translation: x' = -2y + 1, y' = 2x + 2, z' = 2z + 3
    let ok = cfg(
        "[[0, -2, 0, 1], [2, 0, 0, 2], [0, 0, 2, 3], [0, 0, 0, 1]]",
        true,
    );
    ok.validate().unwrap();
    let s = super::Similarity::from_rows(&ok.colmap_to_world.unwrap()).unwrap();
    assert!((s.scale - 2.0).abs() < 1e-12);
    let p = s.point(glam::DVec3::X);
    assert!(
        (p - glam::DVec3::new(1.0, 4.0, 3.0)).length() < 1e-12,
        "{p}"
    );
    let bad = [
        (
            "[[1, 0.01, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
            "shears or scales unevenly",
        ),
        (
            "[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
            "shears or scales unevenly",
        ),
        (
            "[[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
            "no mirror",
        ),
        (
            "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]",
            "last row",
        ),
    ];
    for (m, want) in bad {
        let e = cfg(m, true).validate().unwrap_err();
        assert!(
            e.contains("views.to_world is not a similarity") && e.contains(want),
            "{m}: {e}"
        );
    }
    let identity = "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]";
    let e = cfg(identity, false).validate().unwrap_err();
    assert!(e.contains("views.colmap is not"), "{e}");
}
