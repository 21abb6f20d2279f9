//! Every sampled step evaluated for every runner at every pose-noise
//! level ([`evaluate::evaluate_frame`]), and handed on in a fixed order:
//! step by step, level by level, runner by runner (on several threads
//! through [`super::parallel`], in the same order).

use super::evaluation::Evaluation;
use super::instance::Instance;
use super::simulate::simulate_steps;
use super::{Progress, RunError, SimStats, Warnings, parallel};
use crate::config::Settings;
use crate::evaluate::{self, CorrespondenceSource, PairAtLevel};
use crate::sensor::PoseNoiseLabel;

/// Runs the scenario and hands every frame's evaluation to `on_eval`: for
/// each sampled step, each pose-noise level and each runner in order, the
/// step's instances, their pairs at that level, the level, and what
/// [`evaluate::evaluate_frame`] made of them (with `[matching]
/// multi_vehicle`). With `threads` > 1, SUMO and sensing go on in this
/// thread while `threads` others evaluate the steps already sensed (a
/// runner's levels of one step are one task); `on_eval` still sees
/// everything in the same order, so the results do not depend on the
/// number of threads. What the run has to say beside its results goes to
/// `warnings`.
pub fn evaluate_frames(
    settings: &Settings,
    runners: &[CorrespondenceSource],
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    mut on_eval: impl FnMut(
        &[Instance],
        &[PairAtLevel],
        PoseNoiseLabel,
        evaluate::FrameEval,
    ) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    if threads <= 1 {
        let eval = Evaluation::of(settings);
        return simulate_steps(settings, warnings, progress, |step| {
            let evals = runners.iter().map(|r| eval.step(&step, r)).collect();
            eval.hand_on(&step, evals, &mut on_eval)
        });
    }
    parallel::evaluate_frames(settings, runners, threads, warnings, progress, &mut on_eval)
}
