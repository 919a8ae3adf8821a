//! Progress bars for commands that can take more than a second: drawn on stderr when it is a
//! terminal, nothing on a pipe, in a file or with `--quiet` (so logs and scripts see only
//! the results), and never on stdout.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use objloc_core::fuse::replay::{Observer, Stage};

/// A bar counting frames, or a hidden one off a terminal or when `quiet`.
pub fn frames_bar(message: &str, quiet: bool) -> ProgressBar {
    counted_bar(message, "frames", quiet)
}

/// [`frames_bar`] counting `unit` instead of frames (predict classifies each frame once per
/// head: its count is frames times heads, and called frames it read as twice the session).
/// It stays undrawn until [`set_counts`] gives it a total, so that it never shows "0/0".
pub fn counted_bar(message: &str, unit: &str, quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    // No length yet (a hidden bar's is Some(0)): what marks a bar waiting to be drawn.
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::hidden());
    let template =
        format!("{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit} ({{per_sec}}, eta {{eta}})");
    if let Ok(style) = ProgressStyle::with_template(&template) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(message.to_owned());
    bar
}

/// Sets a [`counted_bar`]'s count, drawing it from the first call with a total.
pub fn set_counts(bar: &ProgressBar, done: usize, total: usize) {
    if total > 0 && bar.length().is_none() {
        bar.set_draw_target(ProgressDrawTarget::stderr());
    }
    if total > 0 || bar.length().is_some() {
        bar.set_length(total as u64);
    }
    bar.set_position(done as u64);
}

/// A spinner naming the stage a command is in (for stages without a frame count), or a
/// hidden one off a terminal or when `quiet`.
pub fn stage_spinner(quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new_spinner();
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// The replay's progress as an observer: the frames fused (classified as the first pass goes;
/// a second pass after a rollback counted again); it asks for no frame steps, so it costs
/// nothing.
pub struct ReplayProgress {
    bar: ProgressBar,
}

impl ReplayProgress {
    /// Progress of a replay, drawn as [`frames_bar`] draws.
    pub fn new(quiet: bool) -> Self {
        Self {
            bar: frames_bar("fuse", quiet),
        }
    }
}

impl Observer for ReplayProgress {
    fn wants_steps(&self) -> bool {
        false
    }

    fn on_progress(&mut self, stage: Stage, done: usize, total: usize) {
        let message = match stage {
            Stage::Fuse => "fuse",
        };
        if self.bar.message() != message {
            self.bar.set_message(message);
        }
        set_counts(&self.bar, done, total);
    }
}

impl Drop for ReplayProgress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
