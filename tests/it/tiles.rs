//! Tests of the memory-mapped tile store: round trips, determinism across thread counts and
//! window sizes, refusal of bad files, and (ignored by default) the bounded-RSS measurement.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use kdmap::atlas::store::{window_tiles_for_budget, TileStore, HEADER_BYTES};

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// A 72-byte record shaped like the real per-texel state.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct TexelState {
    l_orig: [f32; 3],
    weight: f32,
    e_d: [f32; 3],
    e_i: [f32; 3],
    k_d: [f32; 3],
    error: f32,
    accum: [f32; 3],
    flags: u32,
}

const _: () = assert!(std::mem::size_of::<TexelState>() == 72);

impl TexelState {
    fn seed() -> Self {
        TexelState {
            l_orig: [0.5; 3],
            weight: 1.0,
            e_d: [1.0; 3],
            e_i: [0.25; 3],
            k_d: [0.5; 3],
            error: 0.0,
            accum: [0.0; 3],
            flags: 0,
        }
    }
}

/// A deterministic per-texel setup from the tile and texel index.
fn setup(tile: usize, recs: &mut [TexelState]) {
    for (k, r) in recs.iter_mut().enumerate() {
        let x = ((tile * 7919 + k * 104_729) % 1000) as f32 / 1000.0;
        r.l_orig = [x, 0.5 * x, 0.25 + x];
        r.e_d = [1.0 + x, 2.0 - x, 1.5];
        r.e_i = [0.1 * x, 0.2, 0.3 * x];
        r.flags = ((tile as u32) << 12) | k as u32;
    }
}

/// One fixed-point-style update like the K_d iteration: k_d = L / (E_d + E_i) clamped,
/// error and running sums updated. Floating point, but per texel, so order-independent.
fn update(_tile: usize, recs: &mut [TexelState]) {
    for r in recs {
        let mut err = 0.0f32;
        for c in 0..3 {
            let e = r.e_d[c] + r.e_i[c] * r.k_d[c];
            let k = (r.l_orig[c] / e.max(1e-6)).clamp(0.0, 1.0);
            err += (k - r.k_d[c]).abs();
            r.k_d[c] = k;
            r.accum[c] += k * r.weight;
        }
        r.error = err;
        r.flags = r.flags.wrapping_add(1);
    }
}

fn tmpdir() -> tempfile::TempDir {
    tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).expect("temp dir")
}

fn build(path: &Path, tiles: usize, texels: usize, window: usize) -> kdmap::Result<()> {
    let mut s = TileStore::create(path, tiles, texels, TexelState::seed())?;
    s.for_each_tile_mut(window, setup)?;
    s.for_each_tile_mut(window, update)?;
    s.for_each_tile_mut(window, update)?;
    s.sync_all()
}

#[test]
fn round_trip_through_reopen() -> TestResult {
    let dir = tmpdir();
    let p = dir.path().join("state.tiles");
    {
        let mut s = TileStore::create(&p, 10, 100, TexelState::seed())?;
        s.set_tag(0x1234)?;
        s.for_each_tile_mut(3, setup)?;
        s.flush()?;
    }
    let s = TileStore::<TexelState>::open(&p)?;
    assert_eq!(
        (s.tile_count(), s.tile_texels(), s.tag()),
        (10, 100, 0x1234)
    );
    for i in 0..10 {
        let mut want = vec![TexelState::seed(); 100];
        setup(i, &mut want);
        assert_eq!(s.read_tile(i)?, want, "tile {i}");
    }
    // the read-only walk sees the same records
    let mismatches = std::sync::atomic::AtomicUsize::new(0);
    s.for_each_tile(4, |i, recs| {
        let mut want = vec![TexelState::seed(); 100];
        setup(i, &mut want);
        if recs != want.as_slice() {
            mismatches.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    })?;
    assert_eq!(mismatches.into_inner(), 0);
    Ok(())
}

#[test]
fn write_tile_then_walk() -> TestResult {
    let dir = tmpdir();
    let p = dir.path().join("w.tiles");
    let mut s = TileStore::create(&p, 4, 9, 0u64)?;
    s.write_tile(2, &[5; 9])?;
    s.for_each_tile_mut(2, |i, t| t.iter_mut().for_each(|v| *v += i as u64))?;
    assert_eq!(s.read_tile(2)?, vec![7; 9]);
    assert_eq!(s.read_tile(3)?, vec![3; 9]);
    Ok(())
}

#[test]
fn identical_with_one_and_two_threads() -> TestResult {
    let dir = tmpdir();
    let mut files = Vec::new();
    for n in [1, 2] {
        let p = dir.path().join(format!("t{n}.tiles"));
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build()?;
        pool.install(|| build(&p, 13, 257, 4))?;
        files.push(std::fs::read(&p)?);
    }
    assert_eq!(files[0].len(), HEADER_BYTES as usize + 13 * 5 * 4096);
    assert!(files[0] == files[1], "1- and 2-thread files differ");
    Ok(())
}

#[test]
fn identical_for_window_sizes() -> TestResult {
    let dir = tmpdir();
    let tiles = 11;
    let mut files = Vec::new();
    for w in [1, 3, tiles, 1000] {
        let p = dir.path().join(format!("w{w}.tiles"));
        build(&p, tiles, 300, w)?;
        files.push(std::fs::read(&p)?);
    }
    for (f, w) in files.iter().zip([1, 3, tiles, 1000]).skip(1) {
        assert!(f == &files[0], "window {w} differs from window 1");
    }
    Ok(())
}

/// Asserts that opening `p` as `TexelState` fails with a message naming the file and
/// containing `what`.
fn assert_refused(p: &Path, what: &str) {
    match TileStore::<TexelState>::open(p) {
        Ok(_) => panic!("{} opened but should be refused", p.display()),
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.contains(&p.display().to_string()),
                "no file name in: {msg}"
            );
            assert!(msg.contains(what), "expected {what:?} in: {msg}");
            assert!(!msg.contains('\n'), "multi-line: {msg}");
        }
    }
}

fn small_store(dir: &Path, name: &str) -> Result<PathBuf, kdmap::Error> {
    let p = dir.join(name);
    TileStore::create(&p, 3, 64, TexelState::seed())?;
    Ok(p)
}

#[test]
fn truncated_file_is_refused() -> TestResult {
    let dir = tmpdir();
    let p = small_store(dir.path(), "trunc.tiles")?;
    let len = std::fs::metadata(&p)?.len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)?
        .set_len(len - 100)?;
    assert_refused(&p, "truncated");
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)?
        .set_len(100)?;
    assert_refused(&p, "truncated");
    std::fs::write(&p, b"")?;
    assert_refused(&p, "truncated");
    Ok(())
}

#[test]
fn trailing_data_is_refused() -> TestResult {
    let dir = tmpdir();
    let p = small_store(dir.path(), "long.tiles")?;
    let len = std::fs::metadata(&p)?.len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)?
        .set_len(len + 1)?;
    assert_refused(&p, "trailing data");
    Ok(())
}

#[test]
fn wrong_magic_is_refused() -> TestResult {
    let dir = tmpdir();
    let p = small_store(dir.path(), "magic.tiles")?;
    let mut bytes = std::fs::read(&p)?;
    bytes[0..8].copy_from_slice(b"NOTTILES");
    std::fs::write(&p, &bytes)?;
    assert_refused(&p, "magic");
    // an unrelated file of plausible size
    std::fs::write(&p, vec![0xab; 8192])?;
    assert_refused(&p, "magic");
    Ok(())
}

#[test]
fn wrong_version_is_refused() -> TestResult {
    let dir = tmpdir();
    let p = small_store(dir.path(), "version.tiles")?;
    let mut bytes = std::fs::read(&p)?;
    bytes[8..12].copy_from_slice(&9u32.to_le_bytes());
    std::fs::write(&p, &bytes)?;
    assert_refused(&p, "version 9");
    Ok(())
}

#[test]
fn wrong_record_size_is_refused() -> TestResult {
    let dir = tmpdir();
    let p = dir.path().join("rec.tiles");
    TileStore::create(&p, 3, 64, [1.0f32; 3])?;
    assert_refused(&p, "12-byte records, expected 72");
    Ok(())
}

#[test]
fn shrunk_while_open_is_an_error_not_a_fault() -> TestResult {
    let dir = tmpdir();
    let p = small_store(dir.path(), "shrink.tiles")?;
    let mut s = TileStore::<TexelState>::open(&p)?;
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)?
        .set_len(HEADER_BYTES + 4096)?;
    let e = s.for_each_tile_mut(1, update).unwrap_err().to_string();
    assert!(
        e.contains("shrank") && e.contains(&p.display().to_string()),
        "{e}"
    );
    assert!(s.for_each_tile(1, |_, _| {}).is_err());
    Ok(())
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let dir = tmpdir();
    let p = dir.path().join("absent.tiles");
    let e = TileStore::<TexelState>::open(&p).unwrap_err().to_string();
    assert!(e.contains(&p.display().to_string()), "{e}");
}

// ---------------------------------------------------------------------------------------
// Bounded-RSS measurement. Run with:
//   cargo test --release --test it tiles::rss_bounded -- --ignored --nocapture
// The test re-executes its own binary so the child's peak RSS (VmHWM) covers only the
// store work. KDMAP_RSS_BUDGET_MIB (default 64) sets the budget; the store is 4x that.
// KDMAP_RSS_DIR (default the target tmp dir) says where the store file goes.

const CHILD_ENV: &str = "KDMAP_RSS_CHILD";

/// `VmRSS` or `VmHWM` of this process, in bytes.
fn proc_status_kib(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kib = line.split_whitespace().nth(1)?.parse::<u64>().ok()?;
    Some(kib * 1024)
}

fn mib(b: u64) -> f64 {
    b as f64 / (1u64 << 20) as f64
}

fn rss_child() -> TestResult {
    let budget_mib: u64 = std::env::var("KDMAP_RSS_BUDGET_MIB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(64);
    let budget = budget_mib << 20;
    let dir = match std::env::var_os("KDMAP_RSS_DIR") {
        Some(d) => tempfile::tempdir_in(d)?,
        None => tmpdir(),
    };
    let path = dir.path().join("rss.tiles");
    let texels = 64 * 64;
    let stride = (texels * std::mem::size_of::<TexelState>()) as u64;
    let tiles = (4 * budget).div_ceil(stride) as usize;

    let baseline = proc_status_kib("VmRSS:").ok_or("no /proc/self/status")?;
    let t0 = Instant::now();
    let mut s = TileStore::create(&path, tiles, texels, TexelState::seed())?;
    let create_s = t0.elapsed().as_secs_f64();
    let after_create = proc_status_kib("VmHWM:").unwrap_or(0);
    // The budget is for the whole process: the window gets what the baseline leaves, less
    // a little for rayon's worker stacks and allocator slack.
    let slack = 4 << 20;
    let window = window_tiles_for_budget(
        budget.saturating_sub(baseline + slack),
        s.tile_stride_bytes(),
    );

    let t1 = Instant::now();
    s.for_each_tile_mut(window, setup)?;
    let setup_s = t1.elapsed().as_secs_f64();
    // two full update passes; report the slower
    let mut update_s = 0f64;
    for _ in 0..2 {
        let t2 = Instant::now();
        s.for_each_tile_mut(window, update)?;
        update_s = update_s.max(t2.elapsed().as_secs_f64());
    }
    let t3 = Instant::now();
    let sum = std::sync::Mutex::new(0f64);
    s.for_each_tile(window, |_, recs| {
        let local: f64 = recs.iter().map(|r| f64::from(r.k_d[0])).sum();
        *sum.lock().unwrap() += local;
    })?;
    let read_s = t3.elapsed().as_secs_f64();
    let peak = proc_status_kib("VmHWM:").ok_or("no VmHWM")?;

    // spot-check the result against a direct computation
    for i in [0, tiles / 2, tiles - 1] {
        let mut want = vec![TexelState::seed(); texels];
        setup(i, &mut want);
        update(i, &mut want);
        update(i, &mut want);
        assert_eq!(s.read_tile(i)?, want, "tile {i}");
    }
    let data = s.data_bytes();
    let gbs = |secs: f64| data as f64 / secs / 1e9;
    println!(
        "RSS_REPORT budget_mib={budget_mib} store_mib={:.1} tiles={tiles} window_tiles={window} \
         window_mib={:.1} threads={} baseline_rss_mib={:.1} hwm_after_create_mib={:.1} \
         peak_rss_mib={:.1} create_s={create_s:.3} setup_pass_s={setup_s:.3} ({:.2} GB/s) \
         update_pass_s={update_s:.3} ({:.2} GB/s) read_pass_s={read_s:.3} ({:.2} GB/s)",
        mib(data),
        mib(window as u64 * s.tile_stride_bytes()),
        rayon::current_num_threads(),
        mib(baseline),
        mib(after_create),
        mib(peak),
        gbs(setup_s),
        gbs(update_s),
        gbs(read_s),
    );
    assert!(
        peak <= budget,
        "peak RSS {:.1} MiB over the {budget_mib} MiB budget",
        mib(peak)
    );
    Ok(())
}

#[test]
#[ignore = "measurement: run in release with --ignored --nocapture"]
fn rss_bounded_with_state_4x_budget() -> TestResult {
    if std::env::var_os(CHILD_ENV).is_some() {
        return rss_child();
    }
    let out = std::process::Command::new(std::env::current_exe()?)
        .args([
            "--exact",
            "tiles::rss_bounded_with_state_4x_budget",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, "1")
        .output()?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    for line in stdout.lines() {
        if let Some(at) = line.find("RSS_REPORT") {
            println!("{}", &line[at..]);
        }
    }
    assert!(
        out.status.success(),
        "child failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(())
}
