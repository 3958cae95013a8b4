//! The `kdmap reconstruct` binary end to end: results are bit-identical whatever the thread
//! count, and bad input gets one clear line and a non-zero exit, never a panic.

use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture(scene: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(scene)
}

fn kdmap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .output()
        .expect("run kdmap")
}

/// Every file under `dir/sub` with its bytes, sorted by name (also used by `resume`).
pub(crate) fn files(dir: &Path, sub: &str) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir.join(sub))
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn one_line_error(out: &std::process::Output) -> String {
    assert!(!out.status.success(), "expected failure");
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "stderr: {err}");
    assert!(!err.contains("panicked"), "stderr: {err}");
    lines[0].to_string()
}

#[test]
fn results_are_bit_identical_for_1_and_2_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox").join("input.xml");
    let mut outs = Vec::new();
    for threads in ["1", "2"] {
        let out = tmp.path().join(format!("t{threads}"));
        let o = kdmap(&[
            "reconstruct",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--photons",
            "100000",
            "--iterations",
            "2",
            "--threads",
            threads,
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        outs.push(out);
    }
    for sub in ["textures", "maps", "renders", "meshes"] {
        let (a, b) = (files(&outs[0], sub), files(&outs[1], sub));
        assert!(!a.is_empty(), "{sub} is empty");
        assert_eq!(a.len(), b.len(), "{sub}");
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.0, y.0);
            assert!(x.1 == y.1, "{sub}/{} differs between 1 and 2 threads", x.0);
        }
    }
    for file in [
        "scene.xml",
        "scene.glb",
        "report/scene_glb.js",
        "renders/masks.json",
    ] {
        let (a, b) = (outs[0].join(file), outs[1].join(file));
        assert!(
            std::fs::read(a).unwrap() == std::fs::read(b).unwrap(),
            "{file}"
        );
    }
    accuracy_of_a_finished_run(&outs[0]);
}

/// `kdmap accuracy` on a finished run: per-shape figures in accuracy.json consistent with
/// the scene figure and the truth file, truth/difference previews; a directory without a run
/// is one clear error.
fn accuracy_of_a_finished_run(out: &Path) {
    let truth = fixture("cbox").join("truth.xml");
    let o = kdmap(&["accuracy", out.to_str().unwrap(), truth.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("scene: mean relative albedo error"),
        "{stdout}"
    );
    let json = std::fs::read_to_string(out.join("accuracy/accuracy.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    // `--json`: the same document on stdout
    let o = kdmap(&[
        "accuracy",
        out.to_str().unwrap(),
        truth.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(printed, v, "accuracy --json differs from accuracy.json");
    let shapes = v["shapes"].as_array().unwrap();
    assert_eq!(shapes.len(), 7, "{json}");
    let (mut n, mut sum) = (0.0, 0.0);
    for s in shapes {
        let t = s["texels"].as_f64().unwrap();
        let e = s["mean_rel_error"].as_f64().unwrap();
        assert!(t > 0.0 && e > 0.0 && e < 0.5, "{s}");
        n += t;
        sum += t * e;
        let id = s["shape"].as_str().unwrap();
        assert!(out.join(format!("accuracy/{id}_truth.png")).is_file());
        assert!(out.join(format!("accuracy/{id}_diff.png")).is_file());
    }
    let scene = v["mean_rel_error"].as_f64().unwrap();
    assert!((scene - sum / n).abs() < 1e-12, "{scene} vs {}", sum / n);
    // The red wall's truth is the constant of truth.xml, on every texel.
    let left = shapes.iter().find(|s| s["shape"] == "left").unwrap();
    let t: Vec<f64> = left["mean_truth"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    for (a, b) in t.iter().zip([0.63, 0.065, 0.05]) {
        assert!((a - b).abs() < 1e-6, "{t:?}");
    }
    let empty = tempfile::tempdir().unwrap();
    let o = kdmap(&[
        "accuracy",
        empty.path().to_str().unwrap(),
        truth.to_str().unwrap(),
    ]);
    let line = one_line_error(&o);
    assert!(line.contains("report.json"), "{line}");
    assert_eq!(
        o.status.code(),
        Some(66),
        "a missing report is a missing input"
    );
}

#[test]
fn photo_of_the_wrong_size_is_refused_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("run.toml");
    // a 64x64 image from the bad-input fixtures stands in for a 256x256 sensor's photo
    let small = tmp.path().join("small.exr");
    kdmap::image::write_exr_rgb(&small, 64, 64, &vec![glam::Vec3::splat(0.5); 64 * 64], true)
        .unwrap();
    std::fs::write(
        &cfg,
        format!(
            "scene = {:?}\n[views]\ncam_train_0 = {:?}\n",
            fixture("cbox").join("input.xml"),
            small
        ),
    )
    .unwrap();
    let o = kdmap(&[
        "reconstruct",
        cfg.to_str().unwrap(),
        "--out",
        tmp.path().join("out").to_str().unwrap(),
    ]);
    let e = one_line_error(&o);
    assert!(
        e.contains("small.exr") && e.contains("64x64") && e.contains("256x256"),
        "{e}"
    );
    assert_eq!(o.status.code(), Some(65));
}

#[test]
fn impossible_settings_and_bad_config_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox").join("input.xml");
    let o = kdmap(&[
        "reconstruct",
        scene.to_str().unwrap(),
        "--out",
        tmp.path().join("o").to_str().unwrap(),
        "--photons",
        "0",
    ]);
    let e = one_line_error(&o);
    assert!(e.contains("photons"), "{e}");
    assert_eq!(o.status.code(), Some(78), "impossible settings: EX_CONFIG");

    let cfg = tmp.path().join("run.toml");
    std::fs::write(&cfg, "scene = \"x.xml\"\n[solver]\niterations = \"many\"\n").unwrap();
    let o = kdmap(&[
        "reconstruct",
        cfg.to_str().unwrap(),
        "--out",
        tmp.path().join("o").to_str().unwrap(),
    ]);
    let e = one_line_error(&o);
    assert!(e.contains("run.toml") && e.contains("line 3"), "{e}");
    assert_eq!(o.status.code(), Some(65), "a malformed config: EX_DATAERR");

    let o = kdmap(&[
        "reconstruct",
        "/nonexistent/scene.xml",
        "--out",
        tmp.path().join("o").to_str().unwrap(),
    ]);
    let e = one_line_error(&o);
    assert!(e.contains("/nonexistent/scene.xml"), "{e}");
    assert_eq!(o.status.code(), Some(66), "a missing scene: EX_NOINPUT");
}

/// `reconstruct` of the Cornell box into `out` (few photons: it is refused before they
/// matter).
fn reconstruct_into(out: &Path) -> std::process::Output {
    let scene = fixture("cbox").join("input.xml");
    let args = ["--photons", "1000", "--iterations", "1"];
    let out = out.to_str().unwrap();
    kdmap(
        &[
            &["reconstruct", scene.to_str().unwrap(), "--out", out][..],
            &args[..],
        ]
        .concat(),
    )
}

/// The one line of a refused `--out`: it names the path, exits with EX_IOERR, and comes
/// before any work (nothing else on stderr: no loading, atlas or progress lines).
fn refused_out(o: &std::process::Output, out: &Path, why: &str) {
    let e = one_line_error(o);
    assert!(
        e.starts_with(&format!("error: {}: {why}", out.display())),
        "{e}"
    );
    assert_eq!(o.status.code(), Some(74), "an unusable output: EX_IOERR");
    let stderr = String::from_utf8_lossy(&o.stderr);
    let others: Vec<&str> = stderr
        .lines()
        .filter(|l| !l.starts_with("error:"))
        .collect();
    assert!(others.is_empty(), "work before the refusal: {stderr}");
}

#[test]
fn unwritable_output_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    // a regular file where the output directory should be
    let blocker = tmp.path().join("out");
    std::fs::write(&blocker, "not a directory").unwrap();
    refused_out(
        &reconstruct_into(&blocker),
        &blocker,
        "exists and is not a directory",
    );
    // ... or on the way to it
    let under = blocker.join("run");
    refused_out(
        &reconstruct_into(&under),
        &under,
        "cannot create the output directory",
    );
    // `project` checks it the same way
    let scene = fixture("cbox").join("input.xml");
    let o = kdmap(&[
        "project",
        scene.to_str().unwrap(),
        "--out",
        blocker.to_str().unwrap(),
    ]);
    refused_out(&o, &blocker, "exists and is not a directory");
    // a place no one may create a directory in, root included (sysfs)
    let sys = Path::new("/sys/kdmap-out");
    if Path::new("/sys/kernel").is_dir() {
        refused_out(
            &reconstruct_into(sys),
            sys,
            "cannot create the output directory",
        );
    }
}

#[test]
fn an_output_directory_holding_other_files_is_refused_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let home = tmp.path().join("home");
    std::fs::create_dir(&home).unwrap();
    std::fs::write(home.join("thesis.tex"), "mine").unwrap();
    std::fs::create_dir(home.join("maps")).unwrap();
    refused_out(
        &reconstruct_into(&home),
        &home,
        "holds 'thesis.tex', which kdmap did not write",
    );
    let mut left: Vec<_> = std::fs::read_dir(&home)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    left.sort();
    assert_eq!(left, ["maps", "thesis.tex"], "the refusal wrote into it");
}

#[test]
fn a_read_only_output_directory_is_refused_unless_root() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let ro = tmp.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    // root writes through permissions: nothing to refuse then
    let writable = std::fs::write(ro.join("probe"), "x").is_ok();
    let o = reconstruct_into(&ro);
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
    if writable {
        eprintln!("running as root: a read-only directory is writable, not checked");
        return;
    }
    refused_out(&o, &ro, "the output directory is not writable");
}

/// The Cornell box with a large cube under its floor that no photo sees, written to `dir`
/// (meshes and photos from the fixture): most of its covered texels are unobserved.
fn cbox_with_a_hidden_cube(dir: &Path) -> PathBuf {
    let src = fixture("cbox");
    let xml = std::fs::read_to_string(src.join("input.xml")).unwrap();
    let xml = xml.replace(
        "value=\"meshes/",
        &format!("value=\"{}/meshes/", src.display()),
    );
    let cube = "<shape type=\"cube\" id=\"hidden\"><transform name=\"to_world\">\
        <scale value=\"3\"/><translate y=\"-10\"/></transform><bsdf type=\"diffuse\"/></shape>\n\
        </scene>";
    let scene = dir.join("scene.xml");
    std::fs::write(&scene, xml.replace("</scene>", cube)).unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for v in 0..3 {
        let f = format!("cam_train_{v}.exr");
        std::fs::copy(src.join("images").join(&f), dir.join("images").join(&f)).unwrap();
    }
    scene
}

/// `kdmap <command> <scene> --out <out> --strict` with few photons and one iteration.
fn strict_run(command: &str, scene: &Path, out: &Path) -> std::process::Output {
    let (scene, out) = (scene.to_str().unwrap(), out.to_str().unwrap());
    let mut args = vec![command, scene, "--out", out, "--strict"];
    if command == "reconstruct" {
        args.extend(["--preset", "fast", "--iterations", "1"]);
    }
    kdmap(&args)
}

#[test]
fn a_run_whose_photos_see_little_warns_and_fails_only_when_strict() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cbox_with_a_hidden_cube(tmp.path());
    let out = tmp.path().join("out");
    let o = strict_run("reconstruct", &scene, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "--strict with a warning: {err}");
    let warning = err
        .lines()
        .find(|l| l.starts_with("warning: only "))
        .unwrap_or("");
    assert!(
        warning.contains("covered texels (") && warning.contains("of the texture is fill"),
        "{err}"
    );
    // the cause: a cube no camera can see
    assert!(
        warning.contains("No photo could see") && warning.contains("more viewpoints"),
        "{err}"
    );
    assert!(
        err.contains("error: --strict: the run ended with 1 warning(s)"),
        "{err}"
    );
    // the outputs are all there, the warning in the report too
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(
        report["warnings"][0].as_str(),
        warning.strip_prefix("warning: ")
    );
    assert!(out.join("textures/hidden_albedo.exr").is_file());
    // the same run without --strict: the warning, exit code 0; as JSON with --progress json
    let o = kdmap(&[
        "project",
        scene.to_str().unwrap(),
        "--out",
        tmp.path().join("p").to_str().unwrap(),
        "--progress",
        "json",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("{\"warning\":\"only "), "{err}");
}

#[test]
fn a_well_observed_run_has_no_warning_even_when_strict() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox").join("input.xml");
    let o = strict_run("project", &scene, &tmp.path().join("out"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("warning"), "{err}");
}

#[test]
fn project_says_the_photos_gains_as_reconstruct_does() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox").join("input.xml");
    let out = tmp.path().join("out");
    let o = kdmap(&[
        "project",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // estimated by default, from the light the photos show; cbox's photos are one exposure
    let line = (err.lines())
        .find(|l| l.starts_with("note: photo gains"))
        .unwrap_or_else(|| panic!("no gains note: {err}"));
    assert!(line.contains("cam_train_0 1.0"), "{line}");
}

/// A finely tessellated sphere (Mitsuba's built-in, 64 x 128 quads) seen by one 64 x 64 camera:
/// its triangles are a few pixels wide, so one pixel in eight straddles two planes: read
/// too (every visible texel observed), where clean pixels alone leave 87.5%.
fn sphere_scene(dir: &Path) -> PathBuf {
    let scene = dir.join("scene.xml");
    std::fs::write(
        &scene,
        "<scene version=\"3.0.0\">\n\
         <sensor type=\"perspective\" id=\"cam\"><float name=\"fov\" value=\"40\"/>\
         <transform name=\"to_world\"><lookat origin=\"0, 0, 4\" target=\"0, 0, 0\" \
         up=\"0, 1, 0\"/></transform><film type=\"hdrfilm\"><integer name=\"width\" \
         value=\"64\"/><integer name=\"height\" value=\"64\"/><rfilter type=\"box\"/></film>\
         </sensor>\n\
         <emitter type=\"point\"><point name=\"position\" x=\"0\" y=\"2\" z=\"4\"/>\
         <rgb name=\"intensity\" value=\"10, 10, 10\"/></emitter>\n\
         <shape type=\"sphere\" id=\"ball\"><bsdf type=\"diffuse\"/></shape>\n</scene>\n",
    )
    .unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let px = vec![glam::Vec3::splat(0.3); 64 * 64];
    kdmap::image::write_exr_rgb(dir.join("images/cam.exr"), 64, 64, &px, false).unwrap();
    scene
}

#[test]
fn with_fine_geometry_every_texel_a_camera_sees_is_observed() {
    let tmp = tempfile::tempdir().unwrap();
    sphere_scene(tmp.path());
    let run = tmp.path().join("run.toml");
    let toml = "scene = \"scene.xml\"\n[projection]\nfine_geometry = true\n";
    std::fs::write(&run, toml).unwrap();
    let out = tmp.path().join("out");
    let o = kdmap(&[
        "project",
        run.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // "projected 1 views onto 1 shapes: O of C surface texels observed (x%; V visible ..."
    let num = |after: &str| -> u64 {
        let rest = &text[text.find(after).unwrap() + after.len()..];
        rest.split(|c: char| !c.is_ascii_digit())
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (observed, visible) = (num("shapes: "), num("%; "));
    assert!(visible > 100, "{text}");
    assert!(
        observed as f64 >= 0.97 * visible as f64,
        "of {visible} visible texels only {observed} observed: {text}"
    );
}
