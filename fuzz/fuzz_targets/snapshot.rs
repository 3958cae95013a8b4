//! Fuzz target: opening a state snapshot / tile store (`state.<seq>.tiles`) as a resumed run
//! does, then reading every tile through the memory maps. The bytes are written to one
//! temporary file per process (the store is file-backed by design).
#![no_main]

use kdmap::atlas::store::TexelState;
use kdmap::atlas::store::TileStore;
use libfuzzer_sys::fuzz_target;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

fn file() -> &'static PathBuf {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    let (_, p) = DIR.get_or_init(|| {
        let d = tempfile::Builder::new()
            .prefix("kdmap-fuzz-snapshot")
            .tempdir_in(shm())
            .unwrap();
        let p = d.path().join("state.1.tiles");
        (d, p)
    });
    p
}

/// RAM-backed temporary files where there are (the target writes one file per input).
fn shm() -> PathBuf {
    let s = PathBuf::from("/dev/shm");
    if s.is_dir() {
        s
    } else {
        std::env::temp_dir()
    }
}

fuzz_target!(|data: &[u8]| {
    let p = file();
    std::fs::write(p, data).unwrap();
    let Ok(store) = TileStore::<TexelState>::open(p) else {
        return;
    };
    let records = AtomicUsize::new(0);
    store
        .for_each_tile(1, |_, tile: &[TexelState]| {
            records.fetch_add(tile.len(), Ordering::Relaxed);
        })
        .unwrap();
    let want = store.tile_count() * store.tile_texels();
    assert_eq!(records.into_inner(), want);
    if store.tile_count() > 0 {
        assert_eq!(store.read_tile(0).unwrap().len(), store.tile_texels());
    }
});
