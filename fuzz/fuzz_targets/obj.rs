//! Fuzz target: the OBJ mesh reader on arbitrary bytes (what `load_obj` does after reading).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = kdmap::scene::mesh::parse_obj_bytes(data, Path::new("fuzz.obj"));
});
