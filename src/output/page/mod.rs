//! `<out>/report.html`: one page a user opens after a run, from the output directory, with no
//! server and nothing fetched from the network. The summary first (scene, sizes, method, time,
//! memory, fit, scores against a truth, warnings), then each view (photo | re-render | error,
//! wipe, zoom, values under the pointer), each shape (table, albedo, maps with their scales),
//! the plots, the paper's table, the capture calibration and a 3D view of `scene.glb`.
//!
//! Its files live under `<out>/report/` (`assets`); what the page needs beyond `report.json`
//! is kept in `report/facts.json`, so [`rebuild`] (`kdmap report <out>`) makes the page again
//! from the directory alone, e.g. after `kdmap accuracy` added scores. The page holds the
//! run's timings (from `report.json`), so it is not among the outputs compared bit for bit.

pub mod assets;
pub mod facts;
pub mod figures;
pub mod html;
pub mod shapes;
pub mod summary;
pub mod svg;
pub mod tables;
pub mod views;

pub use facts::{white_of, Facts, MapScale, ShapeFacts, ViewFacts};

use crate::base::error::{Error, Result};
use crate::base::fsio;
use crate::report::Report;
use html::{esc, section};
use std::path::{Path, PathBuf};

/// The page's file and its folder, at the top of the output directory.
pub const PAGE: &str = "report.html";
pub const DIR: &str = "report";

/// `<out>/report/`.
pub fn page_dir(out: &Path) -> PathBuf {
    out.join(DIR)
}

/// Everything the page is made from.
pub struct Sources {
    pub out: PathBuf,
    pub report: Option<Report>,
    pub facts: Facts,
    /// `accuracy/accuracy.json`, where `kdmap accuracy` wrote it.
    pub accuracy: Option<serde_json::Value>,
}

/// Write the page of a run that just wrote its outputs: keep `facts`, then the page.
pub fn write_page(out: &Path, report: Option<&Report>, facts: &Facts) -> Result<()> {
    facts.save(&page_dir(out))?;
    let src = Sources {
        out: out.to_path_buf(),
        report: report.cloned(),
        facts: facts.clone(),
        accuracy: read_json(&out.join("accuracy/accuracy.json"))?,
    };
    write_html(&src)
}

/// Make the page again from what `out` holds (`kdmap report`).
pub fn rebuild(out: &Path) -> Result<()> {
    let report_path = out.join("report.json");
    let report = match read_json(&report_path)? {
        Some(v) => Some(
            serde_json::from_value(v)
                .map_err(|e| Error::input(&report_path, format!("not a kdmap report: {e}")))?,
        ),
        None => None,
    };
    let facts = Facts::load(&page_dir(out))?;
    if report.is_none() && facts.command.is_empty() {
        let msg = "not found: the directory holds no finished run (reconstruct or project)";
        return Err(Error::input(&report_path, msg));
    }
    let src = Sources {
        out: out.to_path_buf(),
        report,
        facts,
        accuracy: read_json(&out.join("accuracy/accuracy.json"))?,
    };
    write_html(&src)
}

/// A JSON file, or `None` when it does not exist.
fn read_json(path: &Path) -> Result<Option<serde_json::Value>> {
    match std::fs::read_to_string(path) {
        Ok(t) => serde_json::from_str(&t)
            .map(Some)
            .map_err(|e| Error::input(path, format!("not JSON: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Error::io(path, e)),
    }
}

/// The page's files and then the page.
fn write_html(src: &Sources) -> Result<()> {
    let glb = assets::write_assets(&page_dir(&src.out), &src.out.join("scene.glb"))?;
    let html = document(src, glb);
    fsio::write_atomic(&src.out.join(PAGE), html.as_bytes())
}

/// The whole page.
pub fn document(src: &Sources, glb: bool) -> String {
    let exists = |f: &str| src.out.join(f).is_file();
    let mut parts: Vec<(&str, &str, String)> = vec![("summary", "Summary", summary::summary(src))];
    let f = &src.facts;
    if !f.views.is_empty() {
        let has = |v: &str| exists(&format!("renders/{v}.png"));
        parts.push(("views", "Views", views::views(&f.views, f.error_max, &has)));
    }
    if !f.shapes.is_empty() {
        let atlas = src.report.as_ref().map_or(&[][..], |r| &r.atlas[..]);
        let body = shapes::shape_table(&f.shapes, atlas) + &shapes::galleries(&f.shapes, &exists);
        parts.push(("shapes", "Shapes", body));
    }
    if let Some(r) = &src.report {
        parts.push(("plots", "Convergence, time and memory", figures::figures(r)));
        if !r.table.is_empty() {
            parts.push((
                "table",
                "Photo against re-render, per view and shape",
                tables::paper_table(r),
            ));
        }
        if !r.capture.is_empty() {
            parts.push((
                "capture",
                "Capture calibration",
                tables::capture_table(&r.capture),
            ));
        }
        if !r.poses.is_empty() {
            parts.push(("poses", "Camera poses", tables::pose_table(&r.poses)));
        }
    }
    if glb {
        parts.push(("scene3d", "3D view of scene.glb", scene_3d()));
    }
    page(src, &parts)
}

/// The 3D view: `<model-viewer>` on `scene.glb`, given to it by `kdmap.js`.
fn scene_3d() -> String {
    "<p>Drag to orbit, scroll to zoom, right-drag to pan: the recovered albedo textures on the \
     meshes (<a href=\"scene.glb\">scene.glb</a>), under the viewer's neutral light.</p>\
     <model-viewer id=\"viewer3d\" camera-controls interaction-prompt=\"none\" \
     shadow-intensity=\"0\" alt=\"the recovered scene in 3D\"></model-viewer>"
        .to_string()
}

/// The page around its sections: head, table of contents, scripts.
fn page(src: &Sources, parts: &[(&str, &str, String)]) -> String {
    let title = match &src.report {
        Some(r) => format!("kdmap: {}", r.settings.scene.display()),
        None => format!("kdmap {}: {}", src.facts.command, src.out.display()),
    };
    let mut s = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{t}</title><link rel=\"stylesheet\" href=\"report/kdmap.css\"></head>\n\
         <body><header><h1>{t}</h1><nav>",
        t = esc(&title)
    );
    for (id, name, _) in parts {
        s += &format!("<a href=\"#{id}\">{}</a> ", esc(name));
    }
    s.push_str("</nav></header><main>\n");
    for (id, name, body) in parts {
        s += &section(id, name, body);
    }
    let from = match src.report {
        Some(_) => "<a href=\"report.json\">report.json</a> and report/facts.json",
        None => "report/facts.json",
    };
    s.push_str(&format!("</main><footer>Written by kdmap from {from}; "));
    s.push_str(
        "<code>kdmap report &lt;dir&gt;</code> makes it again. 3D view: &lt;model-viewer&gt; \
         (<a href=\"report/LICENSE.model-viewer\">Apache-2.0</a>) with three.js \
         (<a href=\"report/LICENSE.three\">MIT</a>) and Lit \
         (<a href=\"report/LICENSE.lit\">BSD-3-Clause</a>).</footer>\n",
    );
    // kdmap.js loads the viewer and the scene script when the 3D view comes near
    s.push_str("<script src=\"report/kdmap.js\"></script></body></html>\n");
    s
}
