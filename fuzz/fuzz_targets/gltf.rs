//! Fuzz target: the glTF 2.0 scene reader (`.gltf` JSON or binary `.glb`) on arbitrary bytes,
//! as `kdmap` reads a scene file, meshes included. Relative buffer URIs resolve against the
//! `cbox-gltf` fixture, so its `cbox.bin` loads too; `data:` URIs and GLB blobs need no file.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::collections::BTreeMap;
use std::path::Path;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/fixtures/cbox-gltf/fuzz.gltf"
);

fuzz_target!(|data: &[u8]| {
    let views = BTreeMap::new();
    let opts = kdmap::scene::gltf::LoadOptions {
        views: &views,
        photometric_scale: 1.0,
        meshes: true,
    };
    let _ = kdmap::scene::gltf::parse(data, Path::new(SCENE), &opts);
});
