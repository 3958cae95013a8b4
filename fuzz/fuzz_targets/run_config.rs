//! Fuzz target: the TOML run config (parse, then validate, as `Config::load` does).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(cfg) = kdmap::config::Config::from_toml(Path::new("/tmp/fuzz/run.toml"), text) {
            let _ = cfg.validate();
        }
    }
});
