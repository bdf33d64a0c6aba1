//! Progress bars on a terminal (indicatif), for the file side's [`Bars`].

use pkmcal_io::{Bars, Progress};

/// Work items below which no progress bar is shown (it would only flicker).
const PROGRESS_MIN_ITEMS: u64 = 2000;
/// How often a shown bar is redrawn when no step has been done (ms).
const BAR_TICK_MS: u64 = 250;

/// A bar on standard error, hidden when standard error is not a terminal,
/// with `--quiet`, or for small jobs.
pub struct TerminalBars {
    /// `--quiet`: no bar at all.
    pub quiet: bool,
}

struct Bar(indicatif::ProgressBar);

impl Progress for Bar {
    fn inc(&self, n: u64) {
        self.0.inc(n);
    }
    fn inc_length(&self, n: u64) {
        self.0.inc_length(n);
    }
    fn finish(&self) {
        self.0.finish_and_clear();
    }
}

impl Bars for TerminalBars {
    fn bar(&self, len: u64, quiet: bool, what: &str, min_items: u64) -> Box<dyn Progress> {
        use std::io::IsTerminal;
        let bar = indicatif::ProgressBar::new(len);
        let min = if min_items == 0 {
            PROGRESS_MIN_ITEMS
        } else {
            min_items
        };
        let hidden = self.quiet || quiet || len < min || !std::io::stderr().is_terminal();
        if hidden {
            bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        bar.set_style(
            indicatif::ProgressStyle::with_template(&format!(
                "{{bar:40}} {{pos}}/{{len}} {what} ({{elapsed}}, {{eta}} left)"
            ))
            .expect("valid template"),
        );
        if !hidden {
            // Drawn at once and redrawn while the work before the first step
            // runs (a 48-leg plan prepares its candidates for seconds), so a
            // long command is never silent.
            bar.enable_steady_tick(std::time::Duration::from_millis(BAR_TICK_MS));
        }
        Box::new(Bar(bar))
    }
}

/// Notes on standard error, `note: …` (the file side prints nothing itself).
pub struct TerminalNotes;

impl pkmcal_io::Notes for TerminalNotes {
    fn note(&self, note: pkmcal_io::Note) {
        crate::note!("note: {note}");
    }
}
