//! Progress on stderr for long stages, in the form the user chose ([`Mode`]): an indicatif
//! bar with rate and ETA, plain lines (at most one per ~10% or per 10 s, so logs of batch
//! jobs stay short), JSON lines for scripts, or nothing. Notes and per-iteration lines go
//! through here too, so `--quiet` and `--progress json` hold for everything but errors.
//! Writes to stderr never panic: a closed stderr just loses the line.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle, TermLike};
use std::io::{IsTerminal, Write};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// How progress and notes are printed on stderr.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Bars on a terminal, plain lines otherwise; notes.
    Auto,
    /// Bars even when stderr is not a terminal (drawn with ANSI escapes); notes.
    Always,
    /// No progress; notes.
    Never,
    /// One JSON object per line: progress events, notes, iteration statistics.
    Json,
    /// Nothing at all (errors are still printed by the command line).
    Quiet,
}

impl Mode {
    /// Whether notes and per-iteration lines are printed.
    pub fn notes(self) -> bool {
        self != Mode::Quiet
    }
}

/// How long a pass that is quick on small scenes runs before its progress is shown
/// ([`Stage::after`]).
pub const SHOW_AFTER: Duration = Duration::from_secs(2);

/// A stage function's report of `n` more units done (a [`Stage::inc`], or nothing).
pub type Tick<'a> = &'a (dyn Fn(u64) + Sync);

/// A [`Tick`] that reports nowhere (tests, benches).
pub fn no_tick(_: u64) {}

/// One stage's progress.
pub struct Stage {
    name: String,
    total: u64,
    unit: &'static str,
    mode: Mode,
    /// Shown from the start, or once it has run this long (short passes stay silent).
    delay: Duration,
    /// Set when the stage is first shown: its bar, if it draws one.
    shown: OnceLock<Option<ProgressBar>>,
    lines: Mutex<Lines>,
    start: Instant,
}

/// The plain or JSON lines' state: units done, when and at what fraction the last line was.
struct Lines {
    done: u64,
    last_print: Instant,
    last_frac: f64,
}

/// Write one line to stderr, ignoring failures (a closed stderr must not stop a run).
pub fn line(text: &str) {
    let mut e = std::io::stderr().lock();
    let _ = writeln!(e, "{text}");
}

/// Stderr as a terminal for indicatif whatever it is connected to (`Mode::Always`).
#[derive(Debug)]
struct AnsiStderr;

impl AnsiStderr {
    fn put(&self, s: &str) -> std::io::Result<()> {
        std::io::stderr().lock().write_all(s.as_bytes())
    }
}

impl AnsiStderr {
    /// Moves the cursor `n` cells in the direction of ANSI final byte `dir` (A/B/C/D).
    fn cursor(&self, n: usize, dir: char) -> std::io::Result<()> {
        match n {
            0 => Ok(()),
            _ => self.put(&format!("\x1b[{n}{dir}")),
        }
    }
}

impl TermLike for AnsiStderr {
    fn width(&self) -> u16 {
        100
    }
    fn move_cursor_up(&self, n: usize) -> std::io::Result<()> {
        self.cursor(n, 'A')
    }
    fn move_cursor_down(&self, n: usize) -> std::io::Result<()> {
        self.cursor(n, 'B')
    }
    fn move_cursor_right(&self, n: usize) -> std::io::Result<()> {
        self.cursor(n, 'C')
    }
    fn move_cursor_left(&self, n: usize) -> std::io::Result<()> {
        self.cursor(n, 'D')
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.put(&format!("{s}\n"))
    }
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        self.put(s)
    }
    fn clear_line(&self) -> std::io::Result<()> {
        self.put("\r\x1b[2K")
    }
    fn flush(&self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// A rate for the bar: three significant digits with k/M/G (`3.16M/s`, `412/s`, `0.52/s`),
/// where indicatif's own `per_sec` prints four decimals of a seven-digit number.
fn rate_text(r: f64) -> String {
    if !r.is_finite() || r <= 0.0 {
        return "-/s".into();
    }
    let (v, unit) = match r {
        r if r >= 1e9 => (r / 1e9, "G"),
        r if r >= 1e6 => (r / 1e6, "M"),
        r if r >= 1e3 => (r / 1e3, "k"),
        r => (r, ""),
    };
    let digits = match v {
        v if v >= 100.0 => 0,
        v if v >= 10.0 => 1,
        _ => 2,
    };
    format!("{v:.digits$}{unit}/s")
}

fn bar(name: &str, total: u64, target: ProgressDrawTarget) -> ProgressBar {
    let b = ProgressBar::with_draw_target(Some(total), target);
    b.set_style(
        ProgressStyle::with_template(
            "{prefix:>12} [{bar:30}] {human_pos}/{human_len} {rate} eta {eta}",
        )
        .map(|s| {
            s.with_key("rate", |st: &ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = w.write_str(&rate_text(st.per_sec()));
            })
        })
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    b.set_prefix(name.to_string());
    b
}

/// A progress event as one JSON line: `{"stage", "event", "done", "total", "unit", "rate"
/// (units per second), "eta_s"}`.
pub fn json_event(
    stage: &str,
    event: &str,
    done: u64,
    total: u64,
    unit: &str,
    secs: f64,
) -> String {
    let rate = done as f64 / secs.max(1e-9);
    let eta = match rate > 0.0 {
        true => serde_json::json!(total.saturating_sub(done) as f64 / rate),
        false => serde_json::Value::Null,
    };
    serde_json::json!({
        "stage": stage,
        "event": event,
        "done": done,
        "total": total,
        "unit": unit,
        "rate": rate,
        "eta_s": eta,
    })
    .to_string()
}

impl Stage {
    /// Start a stage of `total` units (`unit` names them, e.g. "texels", "photons"), shown
    /// at once.
    pub fn new(mode: Mode, name: &str, total: u64, unit: &'static str) -> Stage {
        let s = Stage::after(mode, name, total, unit, Duration::ZERO);
        s.show_if_due(0);
        s
    }

    /// A stage shown only once it has run for `delay`: a pass that is quick on small scenes
    /// and long on large ones says nothing in the first case and gets its bar, rate and ETA
    /// in the second.
    pub fn after(mode: Mode, name: &str, total: u64, unit: &'static str, delay: Duration) -> Stage {
        let start = Instant::now();
        Stage {
            name: name.to_string(),
            total,
            unit,
            mode,
            delay,
            shown: OnceLock::new(),
            lines: Mutex::new(Lines {
                done: 0,
                last_print: start,
                last_frac: 0.0,
            }),
            start,
        }
    }

    /// Show the stage (its start line or bar, `done` units in) if it is not shown yet and its
    /// delay has passed. Returns whether it is shown.
    fn show_if_due(&self, done: u64) -> bool {
        if self.shown.get().is_some() {
            return true;
        }
        if self.start.elapsed() < self.delay {
            return false;
        }
        self.shown.get_or_init(|| {
            let terminal = std::io::stderr().is_terminal();
            let (name, total, unit) = (&self.name, self.total, self.unit);
            let b = match self.mode {
                Mode::Quiet | Mode::Never => None,
                Mode::Auto if terminal => Some(bar(name, total, ProgressDrawTarget::stderr())),
                Mode::Always => {
                    let target = ProgressDrawTarget::term_like(Box::new(AnsiStderr));
                    Some(bar(name, total, target))
                }
                Mode::Auto => {
                    line(&format!("[{name}] start: {total} {unit}"));
                    None
                }
                Mode::Json => {
                    let secs = self.start.elapsed().as_secs_f64();
                    line(&json_event(name, "start", done, total, unit, secs));
                    None
                }
            };
            if let Some(b) = &b {
                b.set_position(done);
            }
            b
        });
        true
    }

    /// Whether progress goes out as lines (plain or JSON) in this mode.
    fn prints_lines(&self) -> bool {
        match self.mode {
            Mode::Json => true,
            Mode::Auto => !std::io::stderr().is_terminal(),
            _ => false,
        }
    }

    /// Record `n` more units done.
    pub fn inc(&self, n: u64) {
        let mut p = self.lines.lock().unwrap_or_else(|e| e.into_inner());
        p.done += n;
        if !self.show_if_due(p.done - n) {
            return;
        }
        if let Some(Some(b)) = self.shown.get() {
            b.inc(n);
        }
        if !self.prints_lines() {
            return;
        }
        let frac = p.done as f64 / self.total.max(1) as f64;
        if frac - p.last_frac < 0.1 && p.last_print.elapsed() < Duration::from_secs(10) {
            return;
        }
        let el = self.start.elapsed().as_secs_f64();
        if self.mode == Mode::Json {
            line(&json_event(
                &self.name, "progress", p.done, self.total, self.unit, el,
            ));
        } else {
            let rate = p.done as f64 / el.max(1e-9);
            let eta = (self.total.saturating_sub(p.done)) as f64 / rate.max(1e-9);
            line(&format!(
                "[{}] {}/{} {} ({:.0}%), {:.3e} {}/s, eta {:.0} s",
                self.name,
                p.done,
                self.total,
                self.unit,
                100.0 * frac,
                rate,
                self.unit,
                eta
            ));
        }
        p.last_print = Instant::now();
        p.last_frac = frac;
    }

    /// Finish the stage; returns its wall time. A delayed stage that was never shown ends
    /// silently.
    pub fn finish(self) -> Duration {
        let el = self.start.elapsed();
        let Some(shown) = self.shown.get() else {
            return el;
        };
        if let Some(b) = shown {
            b.finish_and_clear();
        }
        if self.mode == Mode::Json {
            let s = el.as_secs_f64();
            line(&json_event(
                &self.name, "done", self.total, self.total, self.unit, s,
            ));
        } else if shown.is_some() || self.prints_lines() {
            line(&format!(
                "[{}] done: {} {} in {:.2} s",
                self.name,
                self.total,
                self.unit,
                el.as_secs_f64()
            ));
        }
        el
    }
}

/// A one-off note on stderr (skipped sensors, masked pixels...), unless quiet; a
/// `{"note": ...}` line in JSON mode.
pub fn note(mode: Mode, msg: &str) {
    match mode {
        Mode::Quiet => {}
        Mode::Json => line(&serde_json::json!({ "note": msg }).to_string()),
        _ => line(&format!("note: {msg}")),
    }
}

/// A warning on stderr, in every mode (quiet too: like an error, it says the result may not
/// be what was asked for): `warning: <msg>`, or `{"warning": msg}` in JSON mode.
pub fn warning(mode: Mode, msg: &str) {
    match mode {
        Mode::Json => line(&serde_json::json!({ "warning": msg }).to_string()),
        _ => line(&format!("warning: {msg}")),
    }
}

/// A result line of a stage on stderr (an iteration's errors), unless quiet: `text` as it
/// is, or `json` as one line in JSON mode.
pub fn report(mode: Mode, text: &str, json: serde_json::Value) {
    match mode {
        Mode::Quiet => {}
        Mode::Json => line(&json.to_string()),
        _ => line(text),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_print_three_significant_digits_with_a_prefix() {
        assert_eq!(rate_text(3_162_962.659_2), "3.16M/s");
        assert_eq!(rate_text(41_234.0), "41.2k/s");
        assert_eq!(rate_text(412.4), "412/s");
        assert_eq!(rate_text(0.524), "0.52/s");
        assert_eq!(rate_text(2.5e9), "2.50G/s");
        assert_eq!(rate_text(0.0), "-/s");
        assert_eq!(rate_text(f64::NAN), "-/s");
    }

    #[test]
    fn json_events_carry_the_documented_keys() {
        let v: serde_json::Value = serde_json::from_str(&json_event(
            "photons 1/6",
            "progress",
            25,
            100,
            "photons",
            5.0,
        ))
        .unwrap();
        assert_eq!(v["stage"], "photons 1/6");
        assert_eq!(v["event"], "progress");
        assert_eq!(v["done"], 25);
        assert_eq!(v["total"], 100);
        assert_eq!(v["unit"], "photons");
        assert_eq!(v["rate"], 5.0);
        assert_eq!(v["eta_s"], 15.0);
        // nothing done yet: no rate, so no ETA
        let v: serde_json::Value =
            serde_json::from_str(&json_event("atlas", "start", 0, 9, "texels", 0.0)).unwrap();
        assert!(v["eta_s"].is_null());
    }

    #[test]
    fn a_delayed_stage_is_shown_only_once_its_delay_has_passed() {
        let shown = |s: &Stage| s.shown.get().is_some();
        assert!(shown(&Stage::new(Mode::Never, "now", 4, "tiles")));
        let quick = Stage::after(Mode::Never, "quick", 10, "tiles", Duration::from_secs(3600));
        quick.inc(10);
        assert!(
            !shown(&quick),
            "a pass that ends before its delay says nothing"
        );
        let slow = Stage::after(Mode::Never, "slow", 10, "tiles", Duration::from_millis(30));
        slow.inc(3);
        assert!(!shown(&slow));
        std::thread::sleep(Duration::from_millis(40));
        slow.inc(1);
        assert!(shown(&slow), "shown at the first unit after the delay");
        assert_eq!(slow.lines.lock().unwrap().done, 4);
    }

    #[test]
    fn only_quiet_silences_notes() {
        for m in [Mode::Auto, Mode::Always, Mode::Never, Mode::Json] {
            assert!(m.notes(), "{m:?}");
        }
        assert!(!Mode::Quiet.notes());
    }
}
