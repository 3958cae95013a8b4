//! Fuzz target: reading a photo as kdmap does (header checks, R/G/B by name, non-finite and
//! negative pixels masked), on arbitrary bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(img) = kdmap::image::read_exr_bytes(data, Path::new("fuzz.exr")) {
        let n = img.width as usize * img.height as usize;
        assert_eq!(img.pixels.len(), n);
        assert_eq!(img.valid.len(), n);
        assert!(img
            .pixels
            .iter()
            .all(|p| p.is_finite() && p.min_element() >= 0.0));
    }
});
