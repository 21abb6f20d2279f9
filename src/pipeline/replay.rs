//! A dataset's run as steps ([`dataset_steps`]): its instances, read from
//! the folder, become the same [`Step`]s a simulation hands out, so that
//! every method, count and table takes one path whoever made the
//! instances. Nodes keep the dataset's order and numbers; each vehicle
//! reports the pose and claims the accuracy the dataset gives at each
//! level. What a dataset lacks is filled so that it carries no
//! information: grey colour, one size for every node, a 1 m position
//! error per axis (said once as a warning).

use std::sync::Arc;

use super::instance::InstanceSide;
use super::simulate::Step;
use super::{Progress, RunError, SimStats, Warnings};
use crate::config::{DatasetSource, Settings};
use crate::dataset::read::{Dataset, DatasetInstance, DatasetNode, DatasetSide};
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::sensor::boxes::Motion;
use crate::sensor::{
    Appearance, Descriptor, DescriptorLaw, Detection, DetectionTruth, Observation,
    ObservationTruth, PoseNoiseLevel, Sensed,
};
use crate::traffic::{StaticScene, TrafficFrame};

/// The position error (1 sigma per axis) of a node whose dataset gives no
/// covariance.
const UNKNOWN_SIGMA_M: f64 = 1.0;
/// The size of a node whose dataset gives none: one for all, so that size
/// tells no two nodes apart.
const UNKNOWN_SIZE_M: [f64; 3] = [4.6, 1.8, 1.5];
/// The colour of a node whose dataset gives none (the detector profiles'
/// colour-blind grey).
const UNKNOWN_COLOUR: [f64; 3] = [0.5; 3];

fn dataset_error(dir: &std::path::Path, why: impl std::fmt::Display) -> RunError {
    RunError::Dataset {
        dir: dir.display().to_string(),
        why: why.to_string(),
    }
}

/// Reads run `source.run` of the dataset and hands its instances to
/// `on_step` as steps, in the dataset's order: the instances of one step
/// that agree on what each vehicle saw share its side (as in a
/// simulation's step); one that disagrees starts another step.
pub(super) fn dataset_steps(
    settings: &Settings,
    source: &DatasetSource,
    warnings: &Warnings,
    mut progress: impl FnMut(Progress),
    mut on_step: impl FnMut(Step) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    let dir = &source.dir;
    let dataset = Dataset::open(dir).map_err(|e| dataset_error(dir, e))?;
    let k = source
        .run
        .ok_or_else(|| dataset_error(dir, "no run of it was chosen"))?;
    check_levels(&dataset, &settings.pose_noise).map_err(|e| dataset_error(dir, e))?;
    warn_missing(&dataset, source, warnings);
    let run = dataset.run(k).map_err(|e| dataset_error(dir, e))?;
    let scene = Arc::new(StaticScene {
        junction_id: run.info.scenario.clone(),
        junction_position_m: Vec2::zeros(),
        buildings: Vec::new(),
        lanes: Vec::new(),
    });
    let total = run.instances.len();
    let mut stats = SimStats::default();
    let mut frame = Frame::default();
    for inst in &run.instances {
        if !frame.admits(inst) {
            stats.n_steps += 1;
            frame.hand_on(&scene, &mut on_step)?;
        }
        frame
            .add(inst, source.descriptor_law)
            .map_err(|e| dataset_error(dir, e))?;
        stats.n_instances += 1;
        progress(Progress {
            time_s: stats.n_instances as f64,
            end_s: total as f64,
            instances: stats.n_instances,
        });
    }
    if !frame.numbers.is_empty() {
        stats.n_steps += 1;
        frame.hand_on(&scene, &mut on_step)?;
    }
    Ok(stats)
}

/// The run's levels must be the dataset's, in its order (the command sets
/// them so).
fn check_levels(dataset: &Dataset, config: &[PoseNoiseLevel]) -> Result<(), String> {
    let labels: Vec<_> = config.iter().map(|l| l.label).collect();
    let theirs: Vec<_> = dataset.levels.iter().map(|l| l.label).collect();
    if labels != theirs {
        let names = |l: &[crate::sensor::PoseNoiseLabel]| {
            l.iter().map(|l| l.as_str()).collect::<Vec<_>>().join(", ")
        };
        return Err(format!(
            "its pose-noise levels are {}, the run's {}",
            names(&theirs),
            names(&labels)
        ));
    }
    Ok(())
}

/// Says once what the dataset lacks and what stands in for it.
fn warn_missing(dataset: &Dataset, source: &DatasetSource, warnings: &Warnings) {
    let has = |column: &str| {
        dataset
            .optional_columns
            .iter()
            .any(|c| c == &format!("nodes.parquet: {column}"))
    };
    let mut lacks = Vec::new();
    if !has("cov_xx_m2") {
        lacks.push(format!(
            "position covariances ({UNKNOWN_SIGMA_M} m per axis is used)"
        ));
    }
    if !has("colour_r") {
        lacks.push("colours (all grey: colour tells nothing)".to_owned());
    }
    if !has("length_m") {
        lacks.push("sizes (one size for all: size tells nothing)".to_owned());
    }
    if !dataset.appearance_width.is_none() && source.descriptor_law.is_none() {
        lacks.push(
            "calibrated appearance vectors (no validation runs to fit them on, or they do not \
             tell objects apart there: unused)"
                .to_owned(),
        );
    }
    if !lacks.is_empty() {
        warnings.say(&format!(
            "dataset {} has no {}",
            dataset.dir.display(),
            lacks.join(", no ")
        ));
    }
}

/// A vehicle's view as an instance of the dataset gives it: its nodes and
/// its pose and claimed accuracy at every level.
struct ReadSide {
    side: DatasetSide,
    levels: Vec<(PoseNoiseLevel, Pose2)>,
}

/// The step being gathered: its sides (one per vehicle id) and instances.
#[derive(Default)]
struct Frame {
    step: u64,
    time_s: f64,
    /// What each side was read from, in the order of `sides` (to tell
    /// whether another instance's view of that vehicle is the same).
    read: Vec<ReadSide>,
    sides: Vec<InstanceSide>,
    pairs: Vec<(usize, usize)>,
    numbers: Vec<usize>,
}

impl Frame {
    /// Whether `inst` belongs to this step: the same step, and every
    /// vehicle it shares with the step seen alike.
    fn admits(&self, inst: &DatasetInstance) -> bool {
        if self.numbers.is_empty() {
            return true;
        }
        inst.step == self.step
            && (0..2).all(|s| {
                let side = &inst.sides[s];
                self.read.iter().all(|r| {
                    r.side.id != side.id
                        || (r.side.nodes == side.nodes && r.levels == at_levels(inst, s))
                })
            })
    }

    fn add(&mut self, inst: &DatasetInstance, law: Option<DescriptorLaw>) -> Result<(), String> {
        if self.numbers.is_empty() {
            self.step = inst.step;
            self.time_s = inst.time_s.unwrap_or(f64::NAN);
        }
        let mut pair = [0; 2];
        for (s, side) in inst.sides.iter().enumerate() {
            pair[s] = match self.read.iter().position(|r| r.side.id == side.id) {
                Some(k) => k,
                None => {
                    let at = at_levels(inst, s);
                    let sensed = sensed(inst, s, law)?;
                    self.sides
                        .push(InstanceSide::read(sensed, at.clone()).map_err(|e| e.to_string())?);
                    let copy = DatasetSide {
                        id: side.id.clone(),
                        nodes: side.nodes.clone(),
                    };
                    self.read.push(ReadSide {
                        side: copy,
                        levels: at,
                    });
                    self.sides.len() - 1
                }
            };
        }
        self.pairs.push((pair[0], pair[1]));
        self.numbers.push(inst.instance as usize);
        Ok(())
    }

    /// Hands the gathered step on and starts afresh.
    fn hand_on(
        &mut self,
        scene: &Arc<StaticScene>,
        on_step: &mut impl FnMut(Step) -> Result<(), RunError>,
    ) -> Result<(), RunError> {
        let f = std::mem::take(self);
        let frame = TrafficFrame {
            step: f.step,
            time_s: f.time_s,
            objects: Vec::new(),
        };
        on_step(Step::numbered(
            Arc::clone(scene),
            frame,
            f.sides,
            f.pairs,
            f.numbers,
        ))
    }
}

/// Side `s` of `inst` at every level: the accuracy it claims (the
/// level's position accuracy and this vehicle's heading accuracy) and the
/// pose it reports.
fn at_levels(inst: &DatasetInstance, s: usize) -> Vec<(PoseNoiseLevel, Pose2)> {
    inst.levels
        .iter()
        .map(|l| {
            let claimed = PoseNoiseLevel {
                label: l.label,
                position_sigma_m: l.position_sigma_m,
                heading_sigma_rad: l.heading_sigma_rad[s],
                correlation_s: None,
            };
            (claimed, l.reported[s])
        })
        .collect()
}

/// A node as the vehicle's detection: what the dataset lacks filled
/// (grey, one size for all, a 1 m error per axis); its appearance vector
/// a descriptor of the fitted `law` (none without one).
fn detection(n: &DatasetNode, law: Option<DescriptorLaw>) -> Detection {
    let size = n.size_m.unwrap_or(UNKNOWN_SIZE_M);
    Detection {
        position_m: n.position_m,
        cov_m2: n
            .cov_m2
            .unwrap_or_else(|| Cov2::identity() * UNKNOWN_SIGMA_M.powi(2)),
        appearance: Appearance {
            class: n.class,
            colour_rgb: n.colour_rgb.unwrap_or(UNKNOWN_COLOUR),
            length_m: size[0],
            width_m: size[1],
            height_m: size[2],
            // An all-zero vector is a node without one (a sender's
            // self-report in coid's own exports).
            descriptor: n
                .appearance
                .clone()
                .filter(|v| v.iter().any(|x| *x != 0.0))
                .zip(law)
                .map(|(values, law)| Descriptor { values, law }),
        },
        motion: n.motion.map(|(heading_rad, speed_mps)| Motion {
            heading_rad,
            speed_mps,
        }),
    }
}

/// The node attributes coid's networks read for `side`'s nodes (class
/// one-hot, colour, size as the networks scale it; what the dataset lacks
/// filled as a run fills it), `n x 13` row-major: what a matcher written
/// elsewhere needs to see a side as coid's networks see it.
pub fn network_node_attributes(side: &DatasetSide) -> Vec<f32> {
    let detections: Vec<Detection> = side.nodes.iter().map(|n| detection(n, None)).collect();
    crate::matching::deep::node_attributes(&detections, crate::sensor::AppearanceWidth::NONE)
}

/// What vehicle `s` of `inst` holds, and the truth beside it; its nodes'
/// appearance vectors as descriptors of the fitted `law` (none without
/// one).
fn sensed(inst: &DatasetInstance, s: usize, law: Option<DescriptorLaw>) -> Result<Sensed, String> {
    let side = &inst.sides[s];
    let mut detections = Vec::with_capacity(side.nodes.len());
    let mut truths = Vec::with_capacity(side.nodes.len());
    for n in &side.nodes {
        detections.push(detection(n, law));
        let real = !n.object_id.is_empty();
        truths.push(DetectionTruth {
            object_id: real.then(|| n.object_id.clone()),
            position_m: n.true_m,
            visible_fraction: n.visible_fraction.unwrap_or(if real { 1.0 } else { 0.0 }),
            sender: n.sender,
        });
    }
    let ego_pose = inst.true_poses[s].unwrap_or_else(|| {
        // No truth to score positions against: the first level's report.
        inst.levels
            .first()
            .map_or(Pose2::identity(), |l| l.reported[s])
    });
    Ok(Sensed {
        observation: Observation {
            ego_id: side.id.clone(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose,
            detections: truths,
        },
        visible: Vec::new(),
    })
}
