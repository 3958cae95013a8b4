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

// ---- glTF -----------------------------------------------------------------------------------

/// One triangle whose POSITION is `accessor` (a JSON object's members, without braces) over
/// buffer view 0 (`view`): three vertices, 36 bytes, in a base64 `data:` URI.
fn gltf_triangle(accessor: &str, view: &str) -> Vec<u8> {
    use base64::Engine as _;
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    let data = base64::engine::general_purpose::STANDARD.encode(&bin);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":[{{"name":"tri","mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{{accessor}}}],"bufferViews":[{{{view}}}],
        "buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{data}"}}]}}"#
    )
    .into_bytes()
}

fn parse_gltf(bytes: &[u8], path: &Path) -> kdmap::Result<kdmap::scene::Scene> {
    let views = std::collections::BTreeMap::new();
    let opts = kdmap::scene::gltf::LoadOptions {
        views: &views,
        photometric_scale: 1.0,
        meshes: true,
    };
    kdmap::scene::gltf::parse(bytes, path, &opts)
}

const VEC3: &str = r#""componentType":5126,"type":"VEC3","min":[0,0,0],"max":[1,1,0]"#;
const VIEW: &str = r#""buffer":0,"byteLength":36"#;

/// The hand-made case: an accessor of `count: 0` made the `gltf` crate's reader
/// compute `count - 1` and panic (debug builds); it is refused, naming the accessor.
#[test]
fn gltf_accessor_of_count_zero_is_refused_not_a_panic() {
    let path = Path::new("count0.gltf");
    let ok = parse_gltf(
        &gltf_triangle(&format!(r#"{VEC3},"bufferView":0,"count":3"#), VIEW),
        path,
    );
    assert_eq!(ok.unwrap().shapes[0].mesh.triangles.len(), 1);
    let bytes = gltf_triangle(&format!(r#"{VEC3},"bufferView":0,"count":0"#), VIEW);
    let e = parse_gltf(&bytes, path).unwrap_err();
    assert!(e.to_string().contains("accessors[0]"), "{e}");
    assert!(e.to_string().contains("count is 0"), "{e}");
    assert_input(Err::<(), _>(e), path);
}

/// The fuzzer's first find: a POSITION attribute naming an accessor that does not exist made
/// `gltf-json`'s own validation index past its accessors and panic (every build).
#[test]
fn gltf_position_naming_no_accessor_is_refused_not_a_panic() {
    let path = Path::new("position.gltf");
    let good = gltf_triangle(&format!(r#"{VEC3},"bufferView":0,"count":3"#), VIEW);
    let text = String::from_utf8(good).unwrap();
    assert!(text.contains(r#""POSITION":0"#));
    let bad = text.replace(r#""POSITION":0"#, r#""POSITION":7"#);
    let e = parse_gltf(bad.as_bytes(), path).unwrap_err();
    assert!(e.to_string().contains("accessor 7 does not exist"), "{e}");
    assert!(e.to_string().contains("POSITION"), "{e}");
    assert_input(Err::<(), _>(e), path);
}

/// The fuzzer's second find: a GLB header whose length is under its own 12 bytes made the
/// `gltf` crate subtract with overflow (debug builds); refused, like one longer than the file.
#[test]
fn glb_header_length_outside_the_file_is_refused_not_a_panic() {
    let path = Path::new("short.glb");
    for length in [0u32, 11, 1 << 30] {
        let mut glb = b"glTF".to_vec();
        glb.extend_from_slice(&2u32.to_le_bytes());
        glb.extend_from_slice(&length.to_le_bytes());
        glb.extend_from_slice(&[0; 20]);
        let e = parse_gltf(&glb, path).unwrap_err();
        assert!(e.to_string().contains("malformed GLB: header"), "{e}");
        assert!(e.to_string().contains(&format!("length {length} ")), "{e}");
        assert_input(Err::<(), _>(e), path);
    }
    let e = parse_gltf(b"glTF\x02\0\0\0", path).unwrap_err();
    assert!(e.to_string().contains("truncated"), "{e}");
}

/// Accessors whose bytes fall outside their view or buffer, a stride shorter than an element
/// (a `debug_assert!` in the crate), a count whose byte range overflows `usize`, and sparse
/// substitutions of count 0: each refused before the `gltf` crate reads them.
#[test]
fn gltf_accessor_ranges_are_checked_before_the_gltf_crate_reads_them() {
    let path = Path::new("ranges.gltf");
    let sparse = |n: u32| {
        format!(
            r#"{VEC3},"bufferView":0,"count":3,"sparse":{{"count":{n},
            "indices":{{"bufferView":0,"componentType":5121}},"values":{{"bufferView":0}}}}"#
        )
    };
    let cases = [
        (
            format!(r#"{VEC3},"bufferView":0,"count":4"#),
            VIEW.to_string(),
        ),
        (
            format!(r#"{VEC3},"bufferView":0,"count":3,"byteOffset":4"#),
            VIEW.into(),
        ),
        (
            format!(r#"{VEC3},"bufferView":0,"count":3"#),
            r#""buffer":0,"byteLength":36,"byteOffset":4"#.into(),
        ),
        (
            format!(r#"{VEC3},"bufferView":0,"count":2"#),
            r#""buffer":0,"byteLength":36,"byteStride":4"#.into(),
        ),
        (
            format!(r#"{VEC3},"bufferView":0,"count":3000000000000000000"#),
            r#""buffer":0,"byteLength":36,"byteStride":12"#.into(),
        ),
        (
            format!(
                r#"{VEC3},"count":3000000000000000000,"sparse":{{"count":1,"indices":{{"bufferView":0,"componentType":5121}},"values":{{"bufferView":0}}}}"#
            ),
            VIEW.into(),
        ),
        (sparse(0), VIEW.into()),
        (sparse(4), VIEW.into()),
    ];
    for (accessor, view) in cases {
        let r = parse_gltf(&gltf_triangle(&accessor, &view), path);
        assert!(
            matches!(&r, Err(e) if e.to_string().contains("accessors[0]")),
            "{accessor} / {view}: {r:?}"
        );
        assert_input(r, path);
    }
}
