//! The settings of one run, pass or sweep point, made from validated
//! settings: each constructor returns a new value and says what differs.
//! Nothing outside `config` writes into `Settings` (an architecture
//! test); what validation finds travels beside them
//! (`pipeline::Found`).

use std::path::Path;

use super::{DatasetSource, Settings};
use crate::matching::Method;
use crate::sensor::PoseNoiseLevel;
use crate::sensor::profile::DetectorProfile;
use crate::sensor::reid::ReidCalibration;
use crate::v2x::V2xSettings;

impl Settings {
    /// The settings of run `seed`: its traffic and sensor seeds both set
    /// to it.
    pub fn for_seed(&self, seed: u64) -> Self {
        let mut s = self.clone();
        s.seeds.traffic = seed;
        s.seeds.sensor = seed;
        s
    }

    /// These settings reading the deep methods' weights, their records and
    /// the baselines' thresholds from `models_dir` (a training seed's
    /// folder, a candidate's, a sweep point's).
    pub fn with_models(&self, models_dir: &Path) -> Self {
        let mut s = self.clone();
        models_dir.clone_into(&mut s.matching.models_dir);
        s
    }

    /// These settings running only `methods`.
    pub fn with_methods(&self, methods: &[Method]) -> Self {
        let mut s = self.clone();
        s.matching.methods = methods.to_vec();
        s
    }

    /// These settings training the networks with or without the
    /// appearance vectors (`[train] appearance_vectors`).
    pub fn with_appearance_vectors(&self, read: bool) -> Self {
        let mut s = self.clone();
        s.train.appearance_vectors = read;
        s
    }

    /// These settings with the V2X channel and messages of a sweep point.
    pub fn with_v2x(&self, v2x: V2xSettings) -> Self {
        let mut s = self.clone();
        s.v2x = v2x;
        s
    }

    /// These settings with the re-identification descriptor calibrated:
    /// `calibration` made on the validation runs
    /// (`experiments::calibrate_appearance`). Unchanged without a
    /// descriptor.
    pub fn with_descriptor_calibration(&self, calibration: ReidCalibration) -> Self {
        let mut s = self.clone();
        if let Some(reid) = s.appearance.reid.as_mut() {
            reid.calibration = Some(calibration);
        }
        s
    }

    /// These settings with every connected vehicle on one detector
    /// profile: `profile` (or the configured one), a mixed fleet and
    /// per-type profiles set aside; returns the keys set aside.
    pub(crate) fn with_one_detector_profile(
        &self,
        profile: Option<DetectorProfile>,
    ) -> (Self, Vec<&'static str>) {
        let mut s = self.clone();
        let d = &mut s.detector;
        if let Some(p) = profile {
            d.profile = p;
        }
        let set_aside = [
            ("mix", !d.mix.is_empty()),
            ("by_type", !d.by_type.is_empty()),
            ("rig_by_type", !d.rig_by_type.is_empty()),
        ]
        .into_iter()
        .filter_map(|(key, set)| set.then_some(key))
        .collect();
        d.mix.clear();
        d.by_type.clear();
        d.rig_by_type.clear();
        (s, set_aside)
    }

    /// These settings sampling instances at most every `[train]
    /// sample_every_s` (a training or validation run as the training loss
    /// sees it).
    pub fn sampled_for_training(&self) -> Self {
        let mut s = self.clone();
        s.scenario.sample_every_s = s.scenario.sample_every_s.max(s.train.sample_every_s);
        s
    }

    /// These settings evaluating the runs of `seeds` (`[eval]
    /// traffic_seeds`).
    pub fn with_test_seeds(&self, seeds: &[u64]) -> Self {
        let mut s = self.clone();
        s.eval.traffic_seeds = seeds.to_vec();
        s
    }

    /// These settings as a report names the runs of `split` evaluated:
    /// the validation seeds as the evaluated ones for "validation", a
    /// dataset's split named.
    pub fn reporting_split(&self, split: &str) -> Self {
        if split == "validation" {
            self.with_test_seeds(&self.train.validation_seeds)
                .with_dataset_split(split)
        } else {
            self.with_dataset_split(split)
        }
    }

    /// These settings (of a dataset) naming its split `split` as the one
    /// evaluated; unchanged without a dataset.
    pub fn with_dataset_split(&self, split: &str) -> Self {
        let mut s = self.clone();
        if let Some(d) = &mut s.dataset {
            d.split = Some(split.to_owned());
        }
        s
    }

    /// These settings reading their instances from a dataset instead of
    /// simulating them: its runs' seeds by split as the training,
    /// validation and test seeds, its pose-noise `levels` as the config's,
    /// and `source`.
    pub fn reading_dataset(
        &self,
        seeds: [Vec<u64>; 3],
        levels: Vec<PoseNoiseLevel>,
        source: DatasetSource,
    ) -> Self {
        let mut s = self.clone();
        let [train, validation, test] = seeds;
        s.train.traffic_seeds = train;
        s.train.validation_seeds = validation;
        s.eval.traffic_seeds = test;
        s.pose_noise = levels;
        s.dataset = Some(source);
        s
    }

    /// These settings (of a dataset) running its run `run` of `split`,
    /// whose seed is `seed` ([`Settings::for_seed`]).
    pub fn of_dataset_run(&self, seed: u64, split: &str, run: usize) -> Self {
        let mut s = self.for_seed(seed);
        if let Some(d) = &mut s.dataset {
            d.split = Some(split.to_owned());
            d.run = Some(run);
        }
        s
    }
}
