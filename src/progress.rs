//! Progress reporting for long stages. The library reports through [`Progress`]; the binary
//! chooses [`Bars`] on a terminal, [`Lines`] when standard error goes to a log (a batch job
//! on a server), or [`Silent`] (`-q`): [`for_stderr`].

use std::io::{IsTerminal, Write};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Receives progress of one stage at a time.
pub trait Progress: Sync {
    /// A stage named `stage` begins, with `total` steps.
    fn start(&self, stage: &str, total: u64);
    /// `n` more steps are done.
    fn advance(&self, n: u64);
    /// The current stage is done.
    fn finish(&self);
    /// Something the user should know that does not stop the run; printed on standard error
    /// by default, whatever else is shown.
    fn warn(&self, msg: &str) {
        eprintln!("scantex: warning: {msg}");
    }
    /// A reporter for work that runs beside the current stage, with its own bar: the atlas
    /// beside binding. Reports nothing unless overridden.
    fn beside(&self) -> Box<dyn Progress + '_> {
        Box::new(Silent)
    }
}

/// Reports nothing.
#[derive(Debug, Default, Clone, Copy)]
pub struct Silent;

impl Progress for Silent {
    fn start(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
}

/// Progress bars on standard error, shown only for stages still running after a second and
/// only when standard error is a terminal (indicatif hides them otherwise). Reporters made by
/// [`Progress::beside`] draw their bars below this one's.
#[derive(Default)]
pub struct Bars {
    /// Where every bar of this reporter and those beside it is drawn.
    multi: indicatif::MultiProgress,
    current: Mutex<Option<(indicatif::ProgressBar, Instant, bool)>>,
}

/// A stage shorter than this shows no bar.
const SHOW_AFTER: Duration = Duration::from_secs(1);

impl Progress for Bars {
    fn start(&self, stage: &str, total: u64) {
        let bar = indicatif::ProgressBar::with_draw_target(
            Some(total),
            indicatif::ProgressDrawTarget::hidden(),
        );
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{msg:>12} [{bar:30}] {pos}/{len} {elapsed_precise} (eta {eta})",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(stage.to_string());
        if let Ok(mut c) = self.current.lock() {
            *c = Some((bar, Instant::now(), false));
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(mut c) = self.current.lock() {
            if let Some((bar, t0, shown)) = c.as_mut() {
                bar.inc(n);
                if !*shown && t0.elapsed() > SHOW_AFTER {
                    *bar = self.multi.add(bar.clone());
                    *shown = true;
                }
            }
        }
    }

    fn finish(&self) {
        if let Ok(mut c) = self.current.lock() {
            if let Some((bar, _, shown)) = c.take() {
                bar.finish_and_clear();
                if shown {
                    self.multi.remove(&bar);
                }
            }
        }
    }

    fn warn(&self, msg: &str) {
        let line = format!("scantex: warning: {msg}");
        self.multi.suspend(|| eprintln!("{line}"));
    }

    fn beside(&self) -> Box<dyn Progress + '_> {
        Box::new(Bars {
            multi: self.multi.clone(),
            current: Mutex::new(None),
        })
    }
}

/// The reporter for standard error: [`Bars`] when it is a terminal, [`Lines`] otherwise.
pub fn for_stderr() -> Box<dyn Progress> {
    if std::io::stderr().is_terminal() {
        Box::new(Bars::default())
    } else {
        Box::new(Lines::default())
    }
}

/// Where [`Lines`] writes.
type Sink = Arc<Mutex<dyn Write + Send>>;

/// A running stage for [`Lines`]: its name, total and count, when it started and when it last
/// printed.
struct Running {
    stage: String,
    total: u64,
    pos: u64,
    start: Instant,
    printed: Instant,
}

/// Plain lines for a log: a stage still running prints where it is every [`Lines::every`],
/// and a stage that took at least [`Lines::after`] says so when it ends. Short runs print
/// nothing; a long one leaves a line or two per stage, never a bar's control characters.
pub struct Lines {
    /// A stage shorter than this prints nothing. Default: 5 s.
    pub after: Duration,
    /// How often a running stage prints its count. Default: 30 s.
    pub every: Duration,
    sink: Sink,
    current: Mutex<Option<Running>>,
}

impl Default for Lines {
    fn default() -> Self {
        Lines::to(Arc::new(Mutex::new(std::io::stderr())))
    }
}

impl Lines {
    /// Lines written to `sink` instead of standard error, with the default intervals.
    pub fn to(sink: Sink) -> Self {
        Lines {
            after: Duration::from_secs(5),
            every: Duration::from_secs(30),
            sink,
            current: Mutex::new(None),
        }
    }

    fn line(&self, text: &str) {
        if let Ok(mut w) = self.sink.lock() {
            // A log that cannot be written to is no reason to stop the work.
            let _ = writeln!(w, "scantex: {text}");
        }
    }
}

impl Progress for Lines {
    fn start(&self, stage: &str, total: u64) {
        if let Ok(mut c) = self.current.lock() {
            let now = Instant::now();
            *c = Some(Running {
                stage: stage.to_string(),
                total,
                pos: 0,
                start: now,
                printed: now,
            });
        }
    }

    fn advance(&self, n: u64) {
        let mut text = None;
        if let Ok(mut c) = self.current.lock() {
            if let Some(r) = c.as_mut() {
                r.pos += n;
                if r.printed.elapsed() >= self.every {
                    r.printed = Instant::now();
                    text = Some(format!(
                        "{}: {}/{} after {:.0} s",
                        r.stage,
                        r.pos,
                        r.total,
                        r.start.elapsed().as_secs_f64()
                    ));
                }
            }
        }
        if let Some(t) = text {
            self.line(&t);
        }
    }

    fn finish(&self) {
        let done = self.current.lock().ok().and_then(|mut c| c.take());
        if let Some(r) = done {
            let took = r.start.elapsed();
            if took >= self.after {
                self.line(&format!(
                    "{}: {}/{} done in {:.1} s",
                    r.stage,
                    r.pos,
                    r.total,
                    took.as_secs_f64()
                ));
            }
        }
    }

    fn warn(&self, msg: &str) {
        self.line(&format!("warning: {msg}"));
    }

    fn beside(&self) -> Box<dyn Progress + '_> {
        Box::new(Lines {
            after: self.after,
            every: self.every,
            sink: self.sink.clone(),
            current: Mutex::new(None),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(after: u64, every: u64) -> (Lines, Arc<Mutex<Vec<u8>>>) {
        let buf = Arc::new(Mutex::new(Vec::new()));
        let mut l = Lines::to(buf.clone());
        l.after = Duration::from_millis(after);
        l.every = Duration::from_millis(every);
        (l, buf)
    }

    fn text(buf: &Arc<Mutex<Vec<u8>>>) -> String {
        String::from_utf8(buf.lock().unwrap().clone()).unwrap()
    }

    #[test]
    fn a_long_stage_prints_its_count_and_its_end() {
        let (l, buf) = lines(0, 0);
        l.start("merging", 4);
        l.advance(1);
        l.advance(3);
        l.finish();
        l.warn("a photograph sees nothing");
        let t = text(&buf);
        let got: Vec<&str> = t.lines().collect();
        assert_eq!(got.len(), 4, "{t}");
        assert!(got[0].starts_with("scantex: merging: 1/4 after "), "{t}");
        assert!(got[1].starts_with("scantex: merging: 4/4 after "), "{t}");
        assert!(got[2].starts_with("scantex: merging: 4/4 done in "), "{t}");
        assert!(got[2].ends_with(" s"), "{t}");
        assert_eq!(got[3], "scantex: warning: a photograph sees nothing");
    }

    #[test]
    fn a_short_stage_prints_nothing() {
        let (l, buf) = lines(60_000, 60_000);
        l.start("atlas", 10);
        l.advance(10);
        l.finish();
        let beside = l.beside();
        beside.start("binding", 3);
        beside.advance(3);
        beside.finish();
        assert_eq!(text(&buf), "");
    }
}
