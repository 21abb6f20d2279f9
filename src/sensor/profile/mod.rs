//! Detector profiles: detections as real detectors make them, with errors
//! that are *not* what the matchers and the fusion assume.
//!
//! `paper` is the model of [`super::observe`] (Gaussian range and bearing
//! errors, fresh every frame, reported with the covariance they were drawn
//! from). `camera` (a monocular 3D detector) and `lidar` (a 360 deg
//! rotating lidar detector) take their recall and mean translation error
//! per range bin from published figures (`[detector.<profile>]`, with the
//! sources in the config's comments and `docs/detectors.md`), and their
//! errors depart from the matchers' assumption the way real detectors'
//! do:
//!
//! - a depth bias growing with range (the camera),
//! - heavy tails: the per-frame part is Student-t,
//! - a part that persists per (observer, object) over time: a stationary
//!   AR(1) (Ornstein-Uhlenbeck) process with a stated correlation time,
//!   sampled on a fixed 0.1 s grid, a pure function of its name (no state
//!   is carried between frames, so the error at a time does not depend on
//!   which frames were sensed before),
//! - a centre pulled towards the sensor when only part of the object is
//!   visible,
//! - duplicates and ghosts next to real objects, and class confusion by a
//!   matrix.
//!
//! Each detection reports the profile's *nominal* covariance: a zero-mean
//! Gaussian, white in time, of the error's second moments (what a real
//! detector would publish). The true error distribution stays here.
//!
//! `model`: a profile's parameters, their checks and the error scale
//! calibrated per range bin, and the error model itself. `sense`: a
//! profile's sensors on a vehicle detecting a frame's objects. This file:
//! the profiles, and which one each connected vehicle of a fleet carries.

use std::collections::BTreeSet;

use crate::rng::{self, Purpose};

mod model;
mod sense;

pub(crate) use model::{ProfileModel, ProfileParams, RigSensor, range_bin};
pub(crate) use sense::{observe_profile, paper_rig, sensor_in_body_m};

crate::label_enum! { "detector profile";
    /// `[detector] profile`: how the connected vehicles' detectors make
    /// detections.
    #[strum(serialize_all = "lowercase")]
    pub(crate) enum DetectorProfile {
        /// The paper's model (`[camera]`, `[sensor]`): Gaussian range and
        /// bearing errors, fresh every frame, reported with exactly the
        /// covariance they were drawn from.
        Paper,
        /// A monocular 3D camera detector (`[detector.camera]`).
        Camera,
        /// A 360 deg rotating lidar detector (`[detector.lidar]`).
        Lidar,
    }
}

crate::label_enum! { "sensor mount";
    /// Where a profile's sensors sit on the vehicle.
    #[strum(serialize_all = "lowercase")]
    pub(crate) enum Mount {
        /// At the middle of the front bumper (a camera).
        Front,
        /// At the centre of the roof (a rotating lidar).
        Roof,
    }
}

/// `[detector]`: which profile the connected vehicles' detectors follow,
/// and the parameters of the two that are not the paper's.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorSettings {
    pub(crate) profile: DetectorProfile,
    /// A mixed fleet: each profile's share of the connected vehicles
    /// (summing to 1, in label order), drawn per vehicle id; empty: every
    /// vehicle carries `profile`.
    pub(crate) mix: Vec<(DetectorProfile, f64)>,
    /// Profiles by SUMO vehicle type id (`[detector] by_type`): a vehicle
    /// of a listed type carries its profile, whatever `mix` and `profile`
    /// say.
    pub(crate) by_type: Vec<(String, DetectorProfile)>,
    pub(crate) camera: ProfileModel,
    pub(crate) lidar: ProfileModel,
    /// Named rigs (`[detector.rigs]`): a profile's error model on sensors
    /// of their own.
    pub(crate) rigs: Vec<NamedRig>,
    /// Rigs by SUMO vehicle type id (`[detector] rig_by_type`): a vehicle
    /// of a listed type carries its rig, over `by_type`, `mix` and
    /// `profile`. Indices into `rigs`.
    pub(crate) rig_by_type: Vec<(String, usize)>,
}

/// A rig of `[detector.rigs]`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct NamedRig {
    pub(crate) name: String,
    /// Whose error model its sensors have.
    pub(crate) profile: DetectorProfile,
    pub(crate) model: ProfileModel,
}

impl DetectorSettings {
    /// The chosen profile's model (`None`: the paper's).
    pub(crate) fn model(&self) -> Option<&ProfileModel> {
        self.model_of(self.profile)
    }

    /// A profile's model (`None`: the paper's).
    pub(super) fn model_of(&self, profile: DetectorProfile) -> Option<&ProfileModel> {
        match profile {
            DetectorProfile::Paper => None,
            DetectorProfile::Camera => Some(&self.camera),
            DetectorProfile::Lidar => Some(&self.lidar),
        }
    }

    /// The profile connected vehicle `vehicle_id` of SUMO type `type_id`
    /// carries: its type's (`by_type`), else in a mixed fleet one drawn by
    /// the vehicle's id (the same vehicle carries the same profile at
    /// every step), else `profile`.
    pub(super) fn profile_of(
        &self,
        sensor_seed: u64,
        vehicle_id: &str,
        type_id: &str,
    ) -> DetectorProfile {
        if let Some((_, p)) = self.by_type.iter().find(|(t, _)| t == type_id) {
            return *p;
        }
        if self.mix.is_empty() {
            return self.profile;
        }
        let u = rng::unit(
            sensor_seed,
            Purpose::DetectorMix,
            &[rng::hash_str(vehicle_id)],
        );
        let mut acc = 0.0;
        for &(p, share) in &self.mix {
            acc += share;
            if u < acc {
                return p;
            }
        }
        self.mix.last().map_or(self.profile, |m| m.0)
    }

    /// The vehicle types `by_type` and `rig_by_type` name that are not
    /// among `seen` (the types of a run's road users), sorted, each once:
    /// those entries changed nothing.
    pub(crate) fn unused_types<'a>(&'a self, seen: &BTreeSet<String>) -> Vec<&'a str> {
        let named = self.by_type.iter().map(|(t, _)| t.as_str());
        let named = named.chain(self.rig_by_type.iter().map(|(t, _)| t.as_str()));
        let unused: BTreeSet<&str> = named.filter(|t| !seen.contains(*t)).collect();
        unused.into_iter().collect()
    }

    /// What connected vehicle `vehicle_id` of SUMO type `type_id` senses
    /// with: its type's rig (`rig_by_type`), else its profile's model
    /// ([`Self::profile_of`]); `None`: the paper's model.
    pub(crate) fn model_for(
        &self,
        sensor_seed: u64,
        vehicle_id: &str,
        type_id: &str,
    ) -> Option<&ProfileModel> {
        if let Some((_, k)) = self.rig_by_type.iter().find(|(t, _)| t == type_id) {
            return self.rigs.get(*k).map(|r| &r.model);
        }
        self.model_of(self.profile_of(sensor_seed, vehicle_id, type_id))
    }

    /// Whether every vehicle senses with the paper's model.
    pub(crate) fn is_paper(&self) -> bool {
        self.mix.is_empty()
            && self.by_type.is_empty()
            && self.rig_by_type.is_empty()
            && self.profile == DetectorProfile::Paper
    }
}

#[cfg(test)]
mod tests;
