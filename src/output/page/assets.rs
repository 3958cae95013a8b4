//! The page's files besides the HTML, under `<out>/report/`: its style and script, the 3D
//! viewer (`<model-viewer>`, vendored in `assets/model-viewer/` with its licences) and
//! `scene.glb` as base64 in a classic script. Scripts, not modules or fetches: a page opened
//! from `file://` may run classic scripts next to it but may not fetch files or load modules.

use crate::base::error::{Error, Result};
use crate::base::fsio;
use base64::Engine as _;
use std::path::Path;

/// The vendored and own files, written as they are: (name under `report/`, bytes).
pub const STATIC: &[(&str, &[u8])] = &[
    (
        "kdmap.css",
        include_bytes!("../../../assets/page/kdmap.css"),
    ),
    ("kdmap.js", include_bytes!("../../../assets/page/kdmap.js")),
    (
        "model-viewer-umd.min.js",
        include_bytes!("../../../assets/model-viewer/model-viewer-umd.min.js"),
    ),
    (
        "LICENSE.model-viewer",
        include_bytes!("../../../assets/model-viewer/LICENSE"),
    ),
    (
        "LICENSE.three",
        include_bytes!("../../../assets/model-viewer/LICENSE.three"),
    ),
    (
        "LICENSE.lit",
        include_bytes!("../../../assets/model-viewer/LICENSE.lit"),
    ),
];

/// The script that holds `scene.glb`.
pub const GLB_JS: &str = "scene_glb.js";

/// Write the static files into `dir`, and `scene_glb.js` when `glb` exists; returns whether
/// the scene script was written.
pub fn write_assets(dir: &Path, glb: &Path) -> Result<bool> {
    fsio::create_dir(dir)?;
    for (name, bytes) in STATIC {
        let path = dir.join(name);
        // unchanged files are left alone: a rebuild rewrites only what changed
        if std::fs::read(&path).ok().as_deref() != Some(*bytes) {
            fsio::write_atomic(&path, bytes)?;
        }
    }
    let bytes = match std::fs::read(glb) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(Error::io(glb, e)),
    };
    let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);
    let js = format!("window.KDMAP_GLB=\"{b64}\";\n");
    fsio::write_atomic(&dir.join(GLB_JS), js.as_bytes())?;
    Ok(true)
}
