//! Regression tests for the parsers and decoders the fuzzers in `fuzz/` exercise
//! (`tools/fuzz_all.sh`): every input here once crashed, hung or over-allocated in a fuzzer,
//! or pins a property a fuzz target asserts. Each must be refused with a clean, one-line
//! error of the right kind (`Input` for a user's file, `Corrupt` for kdmap's own state).
//! Inputs are inline or small files under `tests/fixtures/fuzz/<target>/`.

use kdmap::base::error::Error;
use kdmap::checkpoint::{self, Manifest, Snapshot};
use kdmap::scene::mesh;
use std::path::{Path, PathBuf};

fn fuzz_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/fuzz")
        .join(target)
}

/// The committed crash inputs of one fuzz target (at least one).
fn cases(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(fuzz_dir(target))
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect();
    v.sort();
    assert!(!v.is_empty(), "no inputs for {target}");
    v
}

/// `r` is an `Input` error naming `path`, on one line.
fn assert_input<T: std::fmt::Debug>(r: kdmap::Result<T>, path: &Path) {
    match r {
        Err(e @ Error::Input { .. }) => {
            let s = e.to_string();
            assert!(s.starts_with(&path.display().to_string()), "{s}");
            assert!(!s.contains('\n'), "{s}");
        }
        other => panic!("{}: expected an input error, got {other:?}", path.display()),
    }
}

// ---- PLY ------------------------------------------------------------------------------------

fn ply_header(format: &str, vertices: u64, faces: u64) -> Vec<u8> {
    format!(
        "ply\nformat {format} 1.0\nelement vertex {vertices}\nproperty float x\n\
         property float y\nproperty float z\nelement face {faces}\n\
         property list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes()
}

#[test]
fn ply_header_claiming_billions_of_elements_is_refused_up_front() {
    let path = Path::new("billions.ply");
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let mut bytes = ply_header(format, 3_000_000_000, 3_000_000_000);
        bytes.extend_from_slice(&[0; 64]);
        let e = mesh::parse_ply(&bytes, path).unwrap_err();
        assert!(e.to_string().contains("6000000000 records"), "{e}");
        assert_input(Err::<(), _>(e), path);
    }
}

#[test]
fn ply_binary_list_longer_than_the_file_is_refused() {
    let path = Path::new("long_list.ply");
    let mut bytes = ply_header("binary_little_endian", 3, 1);
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes.push(255); // 255 indices announced, 4 present
    bytes.extend_from_slice(&[0; 16]);
    assert_input(mesh::parse_ply(&bytes, path), path);
}

/// Found by the `ply` fuzzer: a header number too large for a `u64` (here the format
/// version) made ply-rs's header grammar panic (`unwrap` of a `ParseIntError`).
#[test]
fn ply_header_number_beyond_u64_is_refused_not_a_panic() {
    let path = fuzz_dir("ply").join("version_overflows_u64.ply");
    let bytes = std::fs::read(&path).unwrap();
    let e = mesh::parse_ply(&bytes, &path).unwrap_err();
    assert!(e.to_string().contains("is too large"), "{e}");
    assert_input(Err::<(), _>(e), &path);
    for line in [
        "element vertex 18446744073709551616",
        "format ascii 1.99999999999999999999",
    ] {
        let text = format!("ply\nformat ascii 1.0\n{line}\nproperty float x\nend_header\n");
        let text = text.replacen("format ascii 1.0\nformat", "format", 1);
        assert_input(mesh::parse_ply(text.as_bytes(), &path), &path);
    }
}

/// Every PLY the fuzzer found crashing is refused as malformed input.
#[test]
fn ply_crash_inputs_are_refused() {
    for (path, bytes) in cases("ply") {
        assert_input(mesh::parse_ply(&bytes, &path), &path);
    }
}

// ---- OBJ ------------------------------------------------------------------------------------

#[test]
fn obj_bytes_that_are_not_utf8_are_refused() {
    let path = Path::new("latin1.obj");
    let r = mesh::parse_obj_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n# caf\xe9\nf 1 2 3\n", path);
    assert_input(r, path);
    let ok = mesh::parse_obj_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", path).unwrap();
    assert_eq!(ok.triangles.len(), 1);
}

// ---- checkpoint manifest ------------------------------------------------------------------------

fn manifest_naming(file: &str, seq: u64) -> Manifest<u32> {
    Manifest {
        inputs_hash: 7,
        seq,
        seconds: 1.0,
        snapshot: Some(Snapshot {
            file: file.into(),
            bytes: 4096,
            fnv1a: 0,
        }),
        payload: 42,
    }
}

/// A manifest with a good checksum that names a file outside its directory (or another
/// checkpoint's snapshot) is refused, not followed: `load` and `restore` would read it.
#[test]
fn manifest_naming_a_snapshot_outside_its_directory_is_not_trusted() {
    for (file, seq) in [
        ("../../etc/passwd", 3),
        ("/dev/zero", 3),
        ("state.2.tiles", 3),
        ("state.3.tiles/../../x", 3),
    ] {
        let bytes = checkpoint::encode(&manifest_naming(file, seq)).unwrap();
        let e = checkpoint::decode::<u32>(&bytes).unwrap_err();
        assert!(e.contains("names snapshot"), "{file}: {e}");
    }
    let good = checkpoint::encode(&manifest_naming("state.3.tiles", 3)).unwrap();
    assert_eq!(checkpoint::decode::<u32>(&good).unwrap().payload, 42);

    let dir = tempfile::tempdir().unwrap();
    let bad = checkpoint::encode(&manifest_naming("/dev/zero", 3)).unwrap();
    std::fs::write(dir.path().join(checkpoint::MANIFEST), bad).unwrap();
    let (m, notes) = checkpoint::load::<u32>(dir.path());
    assert!(m.is_none());
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(notes[0].contains("names snapshot"), "{notes:?}");
}

// ---- EXR ------------------------------------------------------------------------------------

/// A 500-byte photo whose header claims 60000 x 60000 pixels: refused from the header, before
/// the decoder allocates 43 GB for its samples.
#[test]
fn exr_header_claiming_more_pixels_than_the_file_holds_is_refused() {
    let path = fuzz_dir("exr").join("huge_data_window.exr");
    let bytes = std::fs::read(&path).unwrap();
    let e = kdmap::image::read_exr_bytes(&bytes, &path).unwrap_err();
    assert!(e.to_string().contains("header declares"), "{e}");
    assert_input(Err::<(), _>(e), &path);
    assert_input(kdmap::image::read_exr(&path), &path);
}
