//! Every sampled step evaluated for every runner at every pose-noise
//! level ([`evaluate::evaluate_frame`]), and handed on in a fixed order:
//! step by step, level by level, runner by runner (on several threads
//! through [`super::parallel`], in the same order).

use super::instance::Instance;
use super::simulate::{Step, simulate_steps};
use super::{Progress, RunError, SimStats, parallel};
use crate::config::Settings;
use crate::evaluate::{self, CorrespondenceSource, PairAtLevel};
use crate::sensor::{PoseNoiseLabel, PoseNoiseLevel};

/// What [`evaluate_frames`] hands on: a step's instances, their pairs at a
/// level, the level, and one runner's evaluation of them.
pub type OnEval<'a> = dyn FnMut(&[Instance], &[PairAtLevel], PoseNoiseLabel, evaluate::FrameEval) -> Result<(), RunError>
    + 'a;

/// Runs the scenario and hands every frame's evaluation to `on_eval`: for
/// each sampled step, each pose-noise level and each runner in order, the
/// step's instances, their pairs at that level, the level, and what
/// [`evaluate::evaluate_frame`] made of them (with `[matching]
/// multi_vehicle`). With `threads` > 1, SUMO and sensing go on in this
/// thread while `threads` others evaluate the steps already sensed (a
/// runner's levels of one step are one task); `on_eval` still sees
/// everything in the same order, so the results do not depend on the
/// number of threads.
pub fn evaluate_frames(
    settings: &Settings,
    runners: &[CorrespondenceSource],
    threads: usize,
    progress: impl FnMut(Progress),
    mut on_eval: impl FnMut(
        &[Instance],
        &[PairAtLevel],
        PoseNoiseLabel,
        evaluate::FrameEval,
    ) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    if threads <= 1 {
        return simulate_steps(settings, progress, |step| {
            let evals = runners
                .iter()
                .map(|r| evaluate_step(settings, &step, r))
                .collect();
            hand_on(settings, &step, evals, &mut on_eval)
        });
    }
    parallel::evaluate_frames(settings, runners, threads, progress, &mut on_eval)
}

/// One runner's evaluation of a step at every pose-noise level, in order.
pub(super) fn evaluate_step(
    settings: &Settings,
    step: &Step,
    runner: &CorrespondenceSource,
) -> Vec<evaluate::FrameEval> {
    let instances = step.instances();
    settings
        .pose_noise
        .iter()
        .map(|level| {
            let pairs = pairs_at(settings, &instances, level);
            evaluate::evaluate_frame(
                &pairs,
                runner,
                &settings.fusion,
                settings.matching.multi_vehicle,
            )
        })
        .collect()
}

fn pairs_at<'a>(
    settings: &Settings,
    instances: &[Instance<'a>],
    level: &PoseNoiseLevel,
) -> Vec<PairAtLevel<'a>> {
    instances
        .iter()
        .map(|i| {
            i.at_level(
                settings.seeds.sensor,
                level,
                settings.v2x.gnss_heading_speed_sigma_mps,
            )
        })
        .collect()
}

/// Hands a step's evaluations (`evals[runner][level]`) to `on_eval`,
/// level by level, runner by runner.
pub(super) fn hand_on(
    settings: &Settings,
    step: &Step,
    evals: Vec<Vec<evaluate::FrameEval>>,
    on_eval: &mut OnEval,
) -> Result<(), RunError> {
    let instances = step.instances();
    let mut by_runner: Vec<std::vec::IntoIter<evaluate::FrameEval>> =
        evals.into_iter().map(Vec::into_iter).collect();
    for level in &settings.pose_noise {
        let pairs = pairs_at(settings, &instances, level);
        for r in &mut by_runner {
            let f = r.next().expect("one evaluation per level");
            on_eval(&instances, &pairs, level.label, f)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::Method;
    use crate::pipeline::runners::runner;
    use crate::pipeline::tests::{settings, two_vehicle_step};

    /// A runner's evaluation of a step: one per level, each of the step's
    /// instance; the oracle finds every common object, at every level.
    #[test]
    fn a_step_is_evaluated_at_every_level() {
        let s = settings();
        let step = two_vehicle_step(0);
        let evals = evaluate_step(&s, &step, &CorrespondenceSource::Oracle);
        assert_eq!(evals.len(), s.pose_noise.len());
        for f in &evals {
            assert_eq!(f.method, Method::Oracle);
            assert_eq!(f.pairs.len(), 1);
            let c = f.pairs[0].counts;
            assert_eq!((c.identified, c.correct, c.ground_truth), (3, 3, 3));
        }
    }

    /// Evaluations are handed on level by level, runner by runner, each
    /// with the step's instances and their pairs at that level.
    #[test]
    fn evaluations_are_handed_on_level_by_level_then_runner_by_runner() {
        let s = settings();
        let step = two_vehicle_step(4);
        let runners = [
            runner(&s, Method::GpsHungarian).unwrap(),
            CorrespondenceSource::Oracle,
        ];
        let evals = runners
            .iter()
            .map(|r| evaluate_step(&s, &step, r))
            .collect();
        let mut seen = Vec::new();
        hand_on(&s, &step, evals, &mut |instances, pairs, level, f| {
            assert_eq!(instances[0].index, 4);
            assert_eq!(pairs[0].level.label, level);
            seen.push((level, f.method));
            Ok(())
        })
        .unwrap();
        let expected: Vec<(PoseNoiseLabel, Method)> = s
            .pose_noise
            .iter()
            .flat_map(|l| [(l.label, Method::GpsHungarian), (l.label, Method::Oracle)])
            .collect();
        assert_eq!(seen, expected);
    }
}
