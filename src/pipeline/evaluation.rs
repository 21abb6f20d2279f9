//! One runner's evaluation of a step at every pose-noise level
//! ([`evaluate::evaluate_frame`]), and a step's evaluations handed on in a
//! fixed order: level by level, runner by runner ([`Evaluation`]).

use super::RunError;
use super::instance::Instance;
use super::simulate::Step;
use crate::config::Settings;
use crate::evaluate::{self, CorrespondenceSource, PairAtLevel};
use crate::fusion::FusionSettings;
use crate::matching::MultiVehicle;
use crate::sensor::{PoseNoiseLabel, PoseNoiseLevel};

/// What [`super::evaluate_frames`] hands on: a step's instances, their
/// pairs at a level, the level, and one runner's evaluation of them.
pub type OnEval<'a> = dyn FnMut(&[Instance], &[PairAtLevel], PoseNoiseLabel, evaluate::FrameEval) -> Result<(), RunError>
    + 'a;

/// What evaluating a step reads of the settings: the pose-noise levels,
/// the sensor seed (which keys the GPS poses' streams), the heading error
/// at speed (`[v2x] gnss_heading_speed_sigma_mps`), `[fusion]` and
/// `[matching] multi_vehicle`.
#[derive(Clone, Copy)]
pub(super) struct Evaluation<'a> {
    levels: &'a [PoseNoiseLevel],
    sensor_seed: u64,
    heading_speed_sigma_mps: f64,
    fusion: &'a FusionSettings,
    multi_vehicle: MultiVehicle,
}

impl<'a> Evaluation<'a> {
    pub(super) fn of(settings: &'a Settings) -> Self {
        Self {
            levels: &settings.pose_noise,
            sensor_seed: settings.seeds.sensor,
            heading_speed_sigma_mps: settings.v2x.gnss_heading_speed_sigma_mps,
            fusion: &settings.fusion,
            multi_vehicle: settings.matching.multi_vehicle,
        }
    }

    /// One runner's evaluation of a step at every pose-noise level, in
    /// order.
    pub(super) fn step(
        &self,
        step: &Step,
        runner: &CorrespondenceSource,
    ) -> Vec<evaluate::FrameEval> {
        let instances = step.instances();
        self.levels
            .iter()
            .map(|level| {
                let pairs = self.pairs_at(&instances, level);
                evaluate::evaluate_frame(&pairs, runner, self.fusion, self.multi_vehicle)
            })
            .collect()
    }

    fn pairs_at<'i>(
        &self,
        instances: &[Instance<'i>],
        level: &PoseNoiseLevel,
    ) -> Vec<PairAtLevel<'i>> {
        instances
            .iter()
            .map(|i| i.at_level(self.sensor_seed, level, self.heading_speed_sigma_mps))
            .collect()
    }

    /// Hands a step's evaluations (`evals[runner][level]`) to `on_eval`,
    /// level by level, runner by runner.
    pub(super) fn hand_on(
        &self,
        step: &Step,
        evals: Vec<Vec<evaluate::FrameEval>>,
        on_eval: &mut OnEval,
    ) -> Result<(), RunError> {
        let instances = step.instances();
        let mut by_runner: Vec<std::vec::IntoIter<evaluate::FrameEval>> =
            evals.into_iter().map(Vec::into_iter).collect();
        for level in self.levels {
            let pairs = self.pairs_at(&instances, level);
            for r in &mut by_runner {
                let f = r.next().expect("one evaluation per level");
                on_eval(&instances, &pairs, level.label, f)?;
            }
        }
        Ok(())
    }
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
        let evals = Evaluation::of(&s).step(&step, &CorrespondenceSource::Oracle);
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
        let eval = Evaluation::of(&s);
        let step = two_vehicle_step(4);
        let runners = [
            runner(&s, Method::GpsHungarian).unwrap(),
            CorrespondenceSource::Oracle,
        ];
        let evals = runners.iter().map(|r| eval.step(&step, r)).collect();
        let mut seen = Vec::new();
        eval.hand_on(&step, evals, &mut |instances, pairs, level, f| {
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
