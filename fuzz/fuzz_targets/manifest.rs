//! Fuzz target: the checkpoint manifest decoder (`progress.kdm`) with the reconstruction's
//! payload type. Arbitrary bytes are decoded as a whole file; then the same bytes are decoded
//! as a payload behind a correct header, to reach the bincode decoding past the checksum.
#![no_main]

use kdmap::checkpoint::{decode, Manifest, VERSION};
use kdmap::pipeline::Progress;
use libfuzzer_sys::fuzz_target;

fn with_header(payload: &[u8]) -> Vec<u8> {
    let sum = kdmap::base::fsio::fnv1a(payload);
    let mut out = format!("KDMCKPT {VERSION} {sum:016x} {}\n", payload.len()).into_bytes();
    out.extend_from_slice(payload);
    out
}

fn check(m: &Manifest<Progress>) {
    if let Some(s) = &m.snapshot {
        // A manifest may only name a snapshot inside its own directory.
        assert!(s.file.starts_with("state.") && !s.file.contains(['/', '\\']));
        assert!(s.file != "." && s.file != "..");
    }
}

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = decode::<Progress>(data) {
        check(&m);
    }
    if let Ok(m) = decode::<Progress>(&with_header(data)) {
        check(&m);
    }
});
