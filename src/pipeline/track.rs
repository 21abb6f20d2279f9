//! `coid track`: cooperation over time, as V2X delivers it
//! ([`crate::v2x`]'s tracking), run step by step: SUMO at `[v2x]
//! step_length_s`, the connected vehicles near the junction sense, and the
//! receivers match with the frame matcher of `[v2x] matcher` at the GNSS
//! level of `[v2x] pose_noise`.

use std::collections::BTreeSet;

use super::instance::InstanceSide;
use super::runners::runner;
use super::simulate::{
    Rig, check_connected_appeared, cooperation, note_connected, note_types, sense,
    warn_unused_types,
};
use super::{Progress, RunError, Warnings};
use crate::config::Settings;
use crate::evaluate::CorrespondenceSource;
use crate::matching::Matcher;
use crate::sensor::PoseNoiseLevel;
use crate::v2x::{TrackResults, Tracking, true_centres};

/// `coid track`: SUMO at `[v2x] step_length_s`; at every step each
/// connected vehicle near the junction tracks its detections (scored by
/// CLEAR-MOT against what its cameras could see), generates a CPM when
/// one is due and sends it to its linked peers over the channel (a
/// `Purpose::Channel` stream per message and receiver); messages that
/// have arrived are matched and associated by their receivers. What the
/// run has to say beside its results goes to `warnings`.
pub fn track(
    settings: &Settings,
    warnings: &Warnings,
    mut progress: impl FnMut(Progress),
) -> Result<TrackResults, RunError> {
    super::simulate::uncalibrated(settings)?;
    let (sc, v) = (&settings.scenario, &settings.v2x);
    let matcher = frame_matcher(settings)?;
    let level = track_level(settings)?;
    let mut sumo = super::simulate::open_sumo(settings, Some(v.step_length_s))?;
    let scene = sumo.static_scene(&sc.junction)?;
    let rig = Rig::of(settings);
    let setup = cooperation(settings, std::slice::from_ref(&level));
    let mut tracking = Tracking::default();
    let mut instances = 0;
    let mut seen_connected = BTreeSet::new();
    let mut seen_types = BTreeSet::new();
    while sumo.time_s() + 1e-6 < sc.end_s {
        let frame = sumo.step()?;
        note_connected(&rig, &frame, &mut seen_connected);
        note_types(&frame, &mut seen_types);
        let sides = sense(&rig, &scene, &frame)?;
        let sensings: Vec<_> = sides.iter().map(InstanceSide::sensing).collect();
        let truth = true_centres(&frame);
        let ctx = setup.at(frame.step, frame.time_s, &truth);
        tracking.step(&ctx, &sensings, matcher.as_ref())?;
        instances += sides.len();
        progress(Progress {
            time_s: frame.time_s,
            end_s: sc.end_s,
            instances,
        });
    }
    sumo.close()?;
    check_connected_appeared(&settings.connected, &seen_connected)?;
    warn_unused_types(&settings.detector, &seen_types, warnings);
    Ok(tracking.finish())
}

/// The frame matcher every receiver runs: `[v2x] matcher`, which must be a
/// matching method.
fn frame_matcher(settings: &Settings) -> Result<Box<dyn Matcher>, RunError> {
    match runner(settings, settings.v2x.matcher)? {
        CorrespondenceSource::Matcher(m) => Ok(m),
        _ => Err(RunError::Worker(
            "[v2x] matcher must be a matching method".into(),
        )),
    }
}

/// The GNSS accuracy of `coid track`: the `[pose_noise]` level `[v2x]
/// pose_noise` names.
fn track_level(settings: &Settings) -> Result<PoseNoiseLevel, RunError> {
    let label = settings.v2x.pose_noise;
    settings
        .pose_noise
        .iter()
        .find(|l| l.label == label)
        .copied()
        .ok_or_else(|| {
            RunError::Worker(format!(
                "[v2x] pose_noise = \"{}\" is not one of the [pose_noise] levels",
                label.as_str()
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::Method;
    use crate::pipeline::tests::settings;
    use crate::sensor::PoseNoiseLabel;

    /// `coid track` needs a matching method and a configured level, and
    /// says which setting is wrong.
    #[test]
    fn the_matcher_and_level_must_be_usable() {
        let mut s = settings();
        assert_eq!(track_level(&s).unwrap().label, s.v2x.pose_noise);
        assert!(frame_matcher(&s).is_ok());
        s.v2x.matcher = Method::Oracle;
        let e = frame_matcher(&s).err().unwrap().to_string();
        assert!(e.contains("[v2x] matcher"), "{e}");
        s.pose_noise.retain(|l| l.label != PoseNoiseLabel::GPS);
        s.v2x.pose_noise = PoseNoiseLabel::GPS;
        let e = track_level(&s).unwrap_err().to_string();
        assert!(e.contains("pose_noise = \"gps\""), "{e}");
    }
}
