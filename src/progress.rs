//! Progress on stderr for long stages: an indicatif bar with rate and ETA on a terminal,
//! plain lines (at most one per ~10% or per 10 s) otherwise, so logs of batch jobs stay short.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Whether progress is printed at all (tests and library users can turn it off).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Auto,
    Quiet,
}

/// One stage's progress.
pub struct Stage {
    name: String,
    total: u64,
    unit: &'static str,
    bar: Option<ProgressBar>,
    plain: Option<Mutex<Plain>>,
    start: Instant,
}

struct Plain {
    done: u64,
    last_print: Instant,
    last_frac: f64,
}

impl Stage {
    /// Start a stage of `total` units (`unit` names them, e.g. "texels", "photons").
    pub fn new(mode: Mode, name: &str, total: u64, unit: &'static str) -> Stage {
        let start = Instant::now();
        let (bar, plain) = match mode {
            Mode::Quiet => (None, None),
            Mode::Auto if std::io::stderr().is_terminal() => {
                let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                b.set_style(
                    ProgressStyle::with_template(
                        "{prefix:>12} [{bar:30}] {human_pos}/{human_len} {per_sec} eta {eta}",
                    )
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
                );
                b.set_prefix(name.to_string());
                (Some(b), None)
            }
            Mode::Auto => {
                eprintln!("[{name}] start: {total} {unit}");
                (
                    None,
                    Some(Mutex::new(Plain {
                        done: 0,
                        last_print: start,
                        last_frac: 0.0,
                    })),
                )
            }
        };
        Stage {
            name: name.to_string(),
            total,
            unit,
            bar,
            plain,
            start,
        }
    }

    /// Record `n` more units done.
    pub fn inc(&self, n: u64) {
        if let Some(b) = &self.bar {
            b.inc(n);
        }
        if let Some(p) = &self.plain {
            let mut p = p.lock().unwrap_or_else(|e| e.into_inner());
            p.done += n;
            let frac = p.done as f64 / self.total.max(1) as f64;
            if frac - p.last_frac >= 0.1 || p.last_print.elapsed() >= Duration::from_secs(10) {
                let el = self.start.elapsed().as_secs_f64();
                let rate = p.done as f64 / el.max(1e-9);
                let eta = (self.total.saturating_sub(p.done)) as f64 / rate.max(1e-9);
                eprintln!(
                    "[{}] {}/{} {} ({:.0}%), {:.3e} {}/s, eta {:.0} s",
                    self.name,
                    p.done,
                    self.total,
                    self.unit,
                    100.0 * frac,
                    rate,
                    self.unit,
                    eta
                );
                p.last_print = Instant::now();
                p.last_frac = frac;
            }
        }
    }

    /// Finish the stage; returns its wall time.
    pub fn finish(self) -> Duration {
        let el = self.start.elapsed();
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
        if self.bar.is_some() || self.plain.is_some() {
            eprintln!(
                "[{}] done: {} {} in {:.2} s",
                self.name,
                self.total,
                self.unit,
                el.as_secs_f64()
            );
        }
        el
    }
}

/// A one-off note on stderr (skipped sensors, masked pixels...), unless quiet.
pub fn note(mode: Mode, msg: &str) {
    if mode == Mode::Auto {
        eprintln!("note: {msg}");
    }
}
