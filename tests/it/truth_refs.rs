//! `kdmap accuracy` against truth files written the way real Mitsuba scenes are: BSDFs declared
//! once with an id and used through `<ref>`, and truths that cover nothing the run
//! reconstructed, which must be refused rather than scored as 0.00%.

use kdmap::accuracy::score_run;
use kdmap::base::progress::Mode;
use kdmap::config::{Config, Preset};
use kdmap::pipeline::reconstruct;
use std::path::Path;
use std::process::Command;

/// A truth of the cbox fixture with every reflectance behind a `<ref>`: plain, with
/// `name="bsdf"`, a twosided bsdf declared with an id, and a twosided around a `<ref>`.
fn named_truth(meshes: &Path) -> String {
    let m = |f: &str| meshes.join(f).display().to_string();
    format!(
        r#"<scene version="3.0.0">
  <bsdf type="diffuse" id="white" name="white"><rgb name="reflectance" value="0.73, 0.73, 0.73"/></bsdf>
  <bsdf type="twosided" id="red"><bsdf type="diffuse"><rgb name="reflectance" value="0.63, 0.065, 0.05"/></bsdf></bsdf>
  <bsdf type="diffuse" id="green_in"><rgb name="reflectance" value="0.14, 0.45, 0.091"/></bsdf>
  <bsdf type="twosided" id="green"><ref id="green_in"/></bsdf>
  <shape type="obj" id="floor"><string name="filename" value="{}"/><ref id="white"/></shape>
  <shape type="obj" id="ceiling"><string name="filename" value="{}"/><ref name="bsdf" id="white"/></shape>
  <shape type="obj" id="back"><string name="filename" value="{}"/><ref id="white"/></shape>
  <shape type="obj" id="left"><string name="filename" value="{}"/><ref id="red"/></shape>
  <shape type="obj" id="right"><string name="filename" value="{}"/><ref id="green"/></shape>
  <shape type="obj" id="short_box"><string name="filename" value="{}"/><ref id="white"/></shape>
  <shape type="obj" id="tall_box"><string name="filename" value="{}"/><ref id="white"/></shape>
</scene>"#,
        m("floor.obj"),
        m("ceiling.obj"),
        m("back.obj"),
        m("left.obj"),
        m("right.obj"),
        m("short_box.obj"),
        m("tall_box.obj"),
    )
}

#[test]
fn truths_with_named_bsdfs_score_and_empty_truths_are_refused() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox");
    let cfg = Config::for_scene(root.join("input.xml")).with_preset(Preset::Fast);
    let out = tempfile::tempdir().unwrap();
    reconstruct(&cfg, out.path(), Mode::Quiet).unwrap();

    // The named truth scores every reconstructed shape exactly as the inline one does.
    let inline = score_run(out.path(), &root.join("truth.xml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let named = dir.path().join("named.xml");
    std::fs::write(&named, named_truth(&root.join("meshes"))).unwrap();
    let by_ref = score_run(out.path(), &named).unwrap();
    assert_eq!(by_ref.shapes.len(), 7, "{:?}", by_ref.shapes);
    assert_eq!(by_ref.shapes, inline.shapes);
    assert!(by_ref.shapes.iter().all(|a| a.texels > 0));
    assert!(by_ref.mean_rel_error > 0.0 && by_ref.mean_rel_error < 0.2);

    // Truths covering no reconstructed shape: other ids, or only the emitter.
    let floor = root.join("meshes/floor.obj").display().to_string();
    let light = root.join("meshes/light.obj").display().to_string();
    for (name, shapes) in [
        (
            "other.xml",
            format!("<shape type=\"obj\" id=\"elsewhere\"><string name=\"filename\" value=\"{floor}\"/><ref id=\"w\"/></shape>"),
        ),
        (
            "light.xml",
            format!("<shape type=\"obj\" id=\"light\"><string name=\"filename\" value=\"{light}\"/><ref id=\"w\"/></shape>"),
        ),
    ] {
        let p = dir.path().join(name);
        let xml = format!(
            "<scene version=\"3.0.0\"><bsdf type=\"diffuse\" id=\"w\"><rgb name=\"reflectance\" value=\"0.5\"/></bsdf>{shapes}</scene>"
        );
        std::fs::write(&p, xml).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_kdmap"))
            .arg("accuracy")
            .arg(out.path())
            .arg(&p)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(65), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(
            err.contains(name) && err.contains("none of the run's reconstructed shapes"),
            "{err}"
        );
        assert!(err.contains("floor"), "the message lists the run's shapes: {err}");
        assert!(String::from_utf8_lossy(&o.stdout).trim().is_empty());
    }
}
