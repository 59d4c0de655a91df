//! Progress of long steps (ray-traced references, bakes, sweeps) as one updating line on
//! stderr: `label  done/total  pct%  ETA`. Shown only when stderr is a terminal; in logs and
//! CI nothing is drawn.
//!
//! A [`Progress`] is the current counter while it lives; code deep inside the step (a ray
//! tracer running on rayon's threads) calls [`advance`] without being handed the counter.
//! [`message`] prints a line without garbling the counter.

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

struct Counter {
    label: String,
    total: u64,
    done: u64,
    start: Instant,
    last_draw: Option<Instant>,
}

static CURRENT: Mutex<Option<Counter>> = Mutex::new(None);
/// Whether a counter is shown (lets [`advance`] skip the lock when none is).
static ACTIVE: AtomicBool = AtomicBool::new(false);

/// Redraws at most this often.
const REDRAW: Duration = Duration::from_millis(100);

fn format_secs(s: f64) -> String {
    if !s.is_finite() {
        "?".into()
    } else if s >= 3600.0 {
        format!(
            "{}h{:02}m",
            (s / 3600.0) as u64,
            ((s % 3600.0) / 60.0) as u64
        )
    } else if s >= 60.0 {
        format!("{}m{:02}s", (s / 60.0) as u64, (s % 60.0) as u64)
    } else {
        format!("{s:.0}s")
    }
}

impl Counter {
    fn line(&self) -> String {
        let frac = if self.total > 0 {
            (self.done as f64 / self.total as f64).min(1.0)
        } else {
            0.0
        };
        let elapsed = self.start.elapsed().as_secs_f64();
        let eta = if self.done > 0 {
            format_secs(elapsed * (1.0 - frac) / frac.max(1e-9))
        } else {
            "?".into()
        };
        format!(
            "  {}  {}/{}  {:.0}%  ETA {eta}",
            self.label,
            self.done.min(self.total),
            self.total,
            100.0 * frac
        )
    }

    fn draw(&mut self, err: &mut impl Write) {
        let _ = write!(err, "\r\x1b[2K{}", self.line());
        let _ = err.flush();
        self.last_draw = Some(Instant::now());
    }
}

fn clear(err: &mut impl Write) {
    let _ = write!(err, "\r\x1b[2K");
}

fn lock() -> std::sync::MutexGuard<'static, Option<Counter>> {
    // A panic while drawing leaves nothing inconsistent: take the state as it is.
    CURRENT.lock().unwrap_or_else(|e| e.into_inner())
}

/// The counter of one long step; cleared from the terminal when dropped.
#[must_use = "the counter disappears when dropped"]
pub struct Progress {
    shown: bool,
}

impl Progress {
    /// Starts counting `total` units of `label` (replacing any counter still shown). Nothing
    /// is drawn when stderr is not a terminal.
    pub fn start(label: &str, total: u64) -> Progress {
        Self::start_on(label, total, std::io::stderr().is_terminal())
    }

    /// As [`Progress::start`], shown or not as told (tests, or a `--quiet` flag).
    pub fn start_on(label: &str, total: u64, shown: bool) -> Progress {
        if shown {
            let mut cur = lock();
            let mut c = Counter {
                label: label.to_string(),
                total,
                done: 0,
                start: Instant::now(),
                last_draw: None,
            };
            c.draw(&mut std::io::stderr().lock());
            *cur = Some(c);
            ACTIVE.store(true, Ordering::Release);
        }
        Progress { shown }
    }

    /// Adds `n` units to this counter.
    pub fn add(&self, n: u64) {
        if self.shown {
            advance(n);
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if self.shown {
            let mut cur = lock();
            ACTIVE.store(false, Ordering::Release);
            if cur.take().is_some() {
                clear(&mut std::io::stderr().lock());
            }
        }
    }
}

/// Adds `n` units to the counter currently shown, if any (cheap when none is). Safe from
/// any thread.
pub fn advance(n: u64) {
    if !ACTIVE.load(Ordering::Acquire) {
        return;
    }
    let mut cur = lock();
    if let Some(c) = cur.as_mut() {
        c.done = c.done.saturating_add(n);
        if c.last_draw.is_none_or(|t| t.elapsed() >= REDRAW) || c.done >= c.total {
            c.draw(&mut std::io::stderr().lock());
        }
    }
}

/// Prints `line` on stderr; a counter being shown is cleared first and redrawn below it.
pub fn message(line: &str) {
    let mut cur = lock();
    let mut err = std::io::stderr().lock();
    if cur.is_some() {
        clear(&mut err);
    }
    let _ = writeln!(err, "{line}");
    if let Some(c) = cur.as_mut() {
        c.draw(&mut err);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_line_shows_count_percentage_and_eta() {
        let c = Counter {
            label: "rays".into(),
            total: 200,
            done: 50,
            start: Instant::now() - Duration::from_secs(10),
            last_draw: None,
        };
        let line = c.line();
        assert!(line.contains("rays  50/200  25%"), "{line}");
        assert!(line.contains("ETA 30s"), "{line}");
        assert_eq!(format_secs(125.0), "2m05s");
    }

    #[test]
    fn hidden_counters_draw_nothing_and_do_not_activate() {
        let p = Progress::start_on("quiet", 10, false);
        p.add(3);
        assert!(!ACTIVE.load(Ordering::Acquire));
        drop(p);
        assert!(lock().is_none());
    }
}
