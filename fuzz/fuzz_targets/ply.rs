//! Fuzz target: the PLY mesh reader (ASCII and binary) on arbitrary bytes; a header claiming
//! billions of elements must be refused without allocating for them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(mesh) = kdmap::scene::mesh::parse_ply(data, Path::new("fuzz.ply")) {
        let n = mesh.positions.len();
        assert!(mesh.triangles.iter().flatten().all(|&i| (i as usize) < n));
    }
});
