//! Validation of `[detector]`: the profile, and each profile's parameters
//! (checked, and their error scale calibrated, by
//! [`ProfileModel::new`](crate::sensor::profile::ProfileModel::new)).

use super::ConfigError;
use super::check::{Checker, num};
use super::raw::{RawDetector, RawProfile, RawRig};
use crate::sensor::CameraSettings;
use crate::sensor::profile::{
    DetectorProfile, DetectorSettings, NamedRig, ProfileModel, ProfileParams, RigSensor,
};

pub(super) fn detector(c: &Checker, d: RawDetector) -> Result<DetectorSettings, ConfigError> {
    let mut mix = Vec::new();
    for (name, share) in &d.mix {
        let p = crate::label::parse::<DetectorProfile>("detector profile", name)
            .map_err(|e| c.invalid("detector.mix", e))?;
        if !(0.0..=1.0).contains(share) {
            return Err(c.invalid(
                "detector.mix",
                format!(
                    "the share of '{name}' must be in [0, 1], got {}",
                    num(*share)
                ),
            ));
        }
        mix.push((p, *share));
    }
    mix.sort_by_key(|m| m.0);
    let total: f64 = mix.iter().map(|m| m.1).sum();
    if !mix.is_empty() && (total - 1.0).abs() > 1e-6 {
        return Err(c.invalid(
            "detector.mix",
            format!("the shares must sum to 1, they sum to {}", num(total)),
        ));
    }
    for (key, map) in [
        ("detector.by_type", &d.by_type),
        ("detector.rig_by_type", &d.rig_by_type),
    ] {
        if map.keys().any(|t| t.trim().is_empty()) {
            return Err(c.invalid(
                key,
                "names an empty vehicle type (keys are SUMO vehicle type ids)".into(),
            ));
        }
    }
    let by_type = d
        .by_type
        .iter()
        .map(|(t, name)| {
            crate::label::parse::<DetectorProfile>("detector profile", name)
                .map(|p| (t.clone(), p))
                .map_err(|e| c.invalid("detector.by_type", format!("type '{t}': {e}")))
        })
        .collect::<Result<_, _>>()?;
    let camera = profile(c, "camera", d.camera)?;
    let lidar = profile(c, "lidar", d.lidar)?;
    let rigs = rigs(c, d.rigs, &camera, &lidar)?;
    let rig_by_type = d
        .rig_by_type
        .iter()
        .map(
            |(t, name)| match rigs.iter().position(|r| &r.name == name) {
                Some(k) => Ok((t.clone(), k)),
                None => Err(c.invalid(
                    "detector.rig_by_type",
                    format!(
                        "type '{t}': no rig '{name}' in [detector.rigs] (there: {})",
                        if rigs.is_empty() {
                            "none".to_owned()
                        } else {
                            rigs.iter()
                                .map(|r| r.name.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        }
                    ),
                )),
            },
        )
        .collect::<Result<_, _>>()?;
    Ok(DetectorSettings {
        profile: d.profile,
        mix,
        by_type,
        camera,
        lidar,
        rigs,
        rig_by_type,
    })
}

/// `[detector.rigs]`: each rig's sensors on its profile's error model.
fn rigs(
    c: &Checker,
    raw: std::collections::BTreeMap<String, RawRig>,
    camera: &ProfileModel,
    lidar: &ProfileModel,
) -> Result<Vec<NamedRig>, ConfigError> {
    let mut rigs = Vec::new();
    for (name, r) in raw {
        let base = match r.profile {
            DetectorProfile::Camera => camera,
            DetectorProfile::Lidar => lidar,
            DetectorProfile::Paper => {
                return Err(c.invalid(
                    "detector.rigs",
                    format!(
                        "rig '{name}': profile must be \"camera\" or \"lidar\" (whose error \
                         model its sensors have); the paper's cameras are [camera]'s"
                    ),
                ));
            }
        };
        let sensors = r
            .sensors
            .iter()
            .map(|s| RigSensor {
                geometry: CameraSettings {
                    fov_rad: s.fov_deg.to_radians(),
                    range_m: s.range_m,
                    height_m: s.height_m,
                    yaw_offsets_rad: vec![s.yaw_deg.to_radians()],
                },
                mount: s.mount,
            })
            .collect();
        let model = base
            .with_rig(sensors)
            .map_err(|e| c.invalid("detector.rigs", format!("rig '{name}': {e}")))?;
        rigs.push(NamedRig {
            name,
            profile: r.profile,
            model,
        });
    }
    Ok(rigs)
}

fn profile(c: &Checker, name: &str, r: RawProfile) -> Result<ProfileModel, ConfigError> {
    let boxes = c.box_errors(
        &format!("detector.{name}"),
        [r.heading_sigma_deg, r.heading_flip_prob, r.speed_sigma_mps],
    )?;
    ProfileModel::new(ProfileParams {
        fov_rad: r.fov_deg.to_radians(),
        range_m: r.range_m,
        height_m: r.height_m,
        mount: r.mount,
        yaw_offsets_rad: r.yaw_offsets_deg.iter().map(|y| y.to_radians()).collect(),
        bin_edges_m: r.bin_edges_m,
        recall: r.recall,
        mean_error_m: r.mean_error_m,
        depth_to_lateral: r.depth_to_lateral,
        depth_bias_per_m: r.depth_bias_per_m,
        tail_dof: r.tail_dof,
        persistent_share: r.persistent_share,
        correlation_time_s: r.correlation_time_s,
        partial_shift: r.partial_shift,
        occlusion_recall_loss: r.occlusion_recall_loss,
        false_positives_per_frame: r.false_positives_per_frame,
        duplicate_prob: r.duplicate_prob,
        ghost_prob: r.ghost_prob,
        ghost_distance_m: r.ghost_distance_m,
        class_confusion: r.class_confusion,
        sees_colour: r.sees_colour,
        boxes,
    })
    .map_err(|e| {
        // The key names the profile's table; an error ends the command, so
        // the few bytes of its name are leaked once.
        let key: &'static str = Box::leak(format!("detector.{name}.{}", e.field).into_boxed_str());
        c.invalid(key, e.message)
    })
}
