//! Pictures (plotters, PNG and SVG), one job a file: `scene` (the scene of
//! one instance, top-down, as the paper draws it, Figs. 5 and 7),
//! `charts` (line panels with bands, grouped bars with intervals, the
//! axis ranges and CDFs they take) and `plots` (`coid eval`'s and `coid
//! batch`'s plots from their data).
//!
//! This module and `io` are the only ones that write result files; it
//! draws what it is given into the folder it is given (a temporary one that
//! `io` renames into place).

mod charts;
mod plots;
mod scene;

use std::sync::Once;

use plotters::prelude::FontStyle;

pub use charts::{Panel, fitted_range, line_panels};
pub use plots::{batch_plot, eval_plots};
pub use scene::{SceneView, render_scene};

static FONT: Once = Once::new();

/// Registers the shipped DejaVu Sans for all text (no system fonts needed).
fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

#[derive(Debug, thiserror::Error)]
#[error("cannot draw {path}: {message}")]
pub struct RenderError {
    pub path: String,
    pub message: String,
}
