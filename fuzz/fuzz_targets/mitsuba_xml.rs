//! Fuzz target: the Mitsuba 3 scene reader on arbitrary text, as `kdmap` reads a scene file.
//! Relative mesh paths resolve against the `cbox` fixture, so real meshes load too; any other
//! name is a missing file, which must be a clean error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/fixtures/cbox/fuzz.xml"
);

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = kdmap::scene::mitsuba::parse(text, Path::new(SCENE));
    }
});
