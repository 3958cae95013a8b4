//! The page's files besides the HTML, under `<out>/report/`: its style and script, the 3D
//! viewer (`<model-viewer>`, vendored in `assets/model-viewer/` with its licences) and
//! `scene.glb` as base64 in a classic script. Scripts, not modules or fetches: a page opened
//! from `file://` may run classic scripts next to it but may not fetch files or load modules.

use crate::base::error::{Error, Result};
use crate::base::fsio;
use base64::write::EncoderWriter;
use std::fs::File;
use std::io::{BufReader, Write as _};
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
    let mut src = match File::open(glb) {
        Ok(f) => BufReader::new(f),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(Error::io(glb, e)),
    };
    let path = dir.join(GLB_JS);
    // streamed: the scene of a large run is hundreds of MB, its base64 a third more
    fsio::write_atomic_buffered(&path, |out| {
        out.write_all(b"window.KDMAP_GLB=\"")
            .map_err(|e| Error::io(&path, e))?;
        let mut enc = EncoderWriter::new(out, &base64::engine::general_purpose::STANDARD);
        std::io::copy(&mut src, &mut enc).map_err(|e| Error::io(glb, e))?;
        let out = enc.finish().map_err(|e| Error::io(&path, e))?;
        out.write_all(b"\";\n").map_err(|e| Error::io(&path, e))
    })?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine as _;

    #[test]
    fn the_scene_script_holds_the_glb_in_base64_as_the_encoder_writes_it_whole() {
        let dir = tempfile::tempdir().unwrap();
        let glb = dir.path().join("scene.glb");
        // every remainder mod 3 (padding), and more than the writers' buffers hold
        for len in [0usize, 1, 2, 3, 100_001, 300_002] {
            let bytes: Vec<u8> = (0..len).map(|i| (i * 7919 % 251) as u8).collect();
            std::fs::write(&glb, &bytes).unwrap();
            let page = dir.path().join(format!("report-{len}"));
            assert!(write_assets(&page, &glb).unwrap());
            let js = std::fs::read_to_string(page.join(GLB_JS)).unwrap();
            let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);
            assert_eq!(js, format!("window.KDMAP_GLB=\"{b64}\";\n"), "{len} bytes");
            assert!(!fsio::tmp_path(&page.join(GLB_JS)).exists());
        }
        let page = dir.path().join("without");
        assert!(!write_assets(&page, &dir.path().join("none.glb")).unwrap());
        assert!(!page.join(GLB_JS).exists());
    }
}
