//! Progress reporting for long stages. The library reports through [`Progress`]; the binary
//! chooses [`Bars`] (indicatif bars on a terminal) or [`Silent`].

use std::sync::Mutex;
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
