//! The detector report (`coid detector`): what the configured detector
//! profile produced on the validation runs, per range bin, beside the
//! figures it was configured with: recall (of every visible object, and of
//! fully visible ones, which the published figures describe), mean
//! translation error, the NEES of the reported covariance (2 and 0.1 %
//! beyond 13.8 when the covariance is the truth), and false positives per
//! sensor and frame.

use super::Table;
use crate::geometry::Vec2;
use crate::sensor::Sensed;

/// NEES of a 2-D Gaussian error beyond which 0.1 % fall (chi2, 2 dof).
pub const NEES_999: f64 = 13.8155;

/// A footprint this visible counts as fully visible.
const FULL: f64 = 0.999;

/// The counts of one range bin.
#[derive(Clone, Debug, Default, PartialEq)]
struct Bin {
    visible: u64,
    detected: u64,
    visible_full: u64,
    detected_full: u64,
    /// Errors of detections of fully visible objects (metres).
    error_full_sum: f64,
    /// Errors of every detection of an object (metres).
    error_sum: f64,
    nees_sum: f64,
    nees_beyond: u64,
}

/// The report's counts over every sensing added.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorStats {
    /// Upper edges of the range bins (metres).
    edges_m: Vec<f64>,
    bins: Vec<Bin>,
    false_positives: u64,
    detections: u64,
    /// Sensor frames: sensings times sensors per vehicle.
    sensor_frames: u64,
}

impl DetectorStats {
    pub fn new(edges_m: Vec<f64>) -> Self {
        let bins = vec![Bin::default(); edges_m.len()];
        DetectorStats {
            edges_m,
            bins,
            false_positives: 0,
            detections: 0,
            sensor_frames: 0,
        }
    }

    fn bin(&self, d_m: f64) -> usize {
        crate::sensor::profile::range_bin(&self.edges_m, d_m)
    }

    /// Adds one vehicle's sensing: distances from the sensor at
    /// `sensor_in_body_m` (ego body frame); `sensors` per vehicle.
    pub fn add(&mut self, sensed: &Sensed, sensor_in_body_m: Vec2, sensors: u64) {
        let ego = &sensed.truth.ego_pose;
        self.sensor_frames += sensors;
        for v in &sensed.visible {
            let d = (ego.to_body(&v.position_m) - sensor_in_body_m).norm();
            let detected = sensed.truth.find(&v.object_id).is_some();
            let full = v.visible_fraction >= FULL;
            let b = self.bin(d);
            let bin = &mut self.bins[b];
            bin.visible += 1;
            bin.detected += u64::from(detected);
            bin.visible_full += u64::from(full);
            bin.detected_full += u64::from(full && detected);
        }
        let dets = sensed.observation.detections.iter();
        for (det, truth) in dets.zip(&sensed.truth.detections) {
            if truth.sender {
                continue;
            }
            self.detections += 1;
            let Some(true_world) = truth.position_m else {
                self.false_positives += 1;
                continue;
            };
            let true_body = ego.to_body(&true_world);
            let e = det.position_m - true_body;
            let nees = det
                .cov_m2
                .try_inverse()
                .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[(0, 0)]);
            let b = self.bin((true_body - sensor_in_body_m).norm());
            let bin = &mut self.bins[b];
            bin.error_sum += e.norm();
            if truth.visible_fraction >= FULL {
                bin.error_full_sum += e.norm();
            }
            bin.nees_sum += nees;
            bin.nees_beyond += u64::from(nees > NEES_999);
        }
    }

    /// One row per bin beside the configured figures (`recall`,
    /// `mean_error_m`; NaN where the profile has none), and the false
    /// positives per sensor frame beside `clutter_per_frame`.
    pub fn table(&self, recall: &[f64], mean_error_m: &[f64], clutter_per_frame: f64) -> Table {
        let ratio = |a: u64, b: u64| {
            if b == 0 {
                f64::NAN
            } else {
                a as f64 / b as f64
            }
        };
        let mean = |s: f64, n: u64| if n == 0 { f64::NAN } else { s / n as f64 };
        let col = |f: &dyn Fn(&Bin) -> f64| self.bins.iter().map(f).collect::<Vec<f64>>();
        let cfg = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(f64::NAN);
        let mut t = Table::default();
        let lower = |k: usize| if k == 0 { 0.0 } else { self.edges_m[k - 1] };
        t.number("from_m", (0..self.bins.len()).map(lower).collect());
        t.number("to_m", self.edges_m.clone());
        t.count("visible", self.bins.iter().map(|b| b.visible).collect());
        t.number("recall", col(&|b| ratio(b.detected, b.visible)));
        t.count(
            "fully_visible",
            self.bins.iter().map(|b| b.visible_full).collect(),
        );
        t.number(
            "recall_fully_visible",
            col(&|b| ratio(b.detected_full, b.visible_full)),
        );
        t.number(
            "recall_configured",
            (0..self.bins.len()).map(|k| cfg(recall, k)).collect(),
        );
        t.count("detected", self.bins.iter().map(|b| b.detected).collect());
        t.number("mean_error_m", col(&|b| mean(b.error_sum, b.detected)));
        t.number(
            "mean_error_fully_visible_m",
            col(&|b| mean(b.error_full_sum, b.detected_full)),
        );
        t.number(
            "mean_error_configured_m",
            (0..self.bins.len()).map(|k| cfg(mean_error_m, k)).collect(),
        );
        t.number("nees_mean", col(&|b| mean(b.nees_sum, b.detected)));
        t.number(
            "nees_beyond_999_share",
            col(&|b| ratio(b.nees_beyond, b.detected)),
        );
        let fp = ratio(self.false_positives, self.sensor_frames);
        t.number(
            "false_positives_per_sensor_frame",
            vec![fp; self.bins.len()],
        );
        t.number(
            "clutter_configured_per_frame",
            vec![clutter_per_frame; self.bins.len()],
        );
        t
    }
}

/// One figure of a [`crate::sensor::reid::ReidFigures`].
type Figure = fn(&crate::sensor::reid::ReidFigures) -> f64;

/// The re-identification descriptor's figures: its targets, what
/// calibration measured on the validation runs' views, and what the
/// descriptors the sensor then gave measure on the same runs (the two
/// agree when the sensor describes as the calibration did).
pub fn reid_table(
    target: &crate::sensor::reid::ReidTarget,
    calibrated: &crate::sensor::reid::ReidFigures,
    measured: &crate::sensor::reid::ReidFigures,
) -> Table {
    let mut t = Table::default();
    let rows: [(&str, Option<f64>, Figure); 6] = [
        ("rank1", Some(target.rank1), |f| f.rank1),
        ("auroc", target.auroc, |f| f.auroc),
        ("queries", None, |f| f.queries as f64),
        ("candidates_per_query", None, |f| f.candidates),
        ("same_object_cosine", None, |f| f.same_cos),
        ("different_object_cosine", None, |f| f.different_cos),
    ];
    t.text("figure", rows.iter().map(|r| r.0.to_owned()).collect());
    t.number(
        "target",
        rows.iter().map(|r| r.1.unwrap_or(f64::NAN)).collect(),
    );
    t.number("calibrated", rows.iter().map(|r| r.2(calibrated)).collect());
    t.number("measured", rows.iter().map(|r| r.2(measured)).collect());
    t.number(
        "measured_over_target",
        rows.iter()
            .map(|r| r.1.map_or(f64::NAN, |v| r.2(measured) / v))
            .collect(),
    );
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Cov2, Pose2};
    use crate::sensor::{
        Appearance, Detection, DetectionTruth, Observation, ObservationTruth, VisibleObject,
    };
    use crate::traffic::ObjectClass;

    fn det(x: f64, cov: f64) -> Detection {
        Detection {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::identity() * cov,
            appearance: Appearance {
                class: ObjectClass::Car,
                colour_rgb: [0.5; 3],
                length_m: 4.6,
                width_m: 1.8,
                height_m: 1.5,
                descriptor: None,
            },
            motion: None,
        }
    }

    fn truth(id: Option<&str>, x: f64, vis: f64) -> DetectionTruth {
        DetectionTruth {
            object_id: id.map(str::to_owned),
            position_m: id.map(|_| Vec2::new(x, 0.0)),
            visible_fraction: vis,
            sender: false,
        }
    }

    /// Two visible objects at 10 m (one detected 1 m off with variance 1:
    /// NEES 1) and one at 40 m missed, and a false positive.
    #[test]
    fn recall_error_nees_and_false_positives_are_counted_per_bin() {
        let visible = |id: &str, x: f64| VisibleObject {
            object_id: id.into(),
            position_m: Vec2::new(x, 0.0),
            visible_fraction: 1.0,
        };
        let sensed = Sensed {
            observation: Observation {
                ego_id: "ego".into(),
                detections: vec![det(11.0, 1.0), det(25.0, 1.0)],
            },
            truth: ObservationTruth {
                ego_pose: Pose2::new(Vec2::zeros(), 0.0),
                detections: vec![truth(Some("a"), 10.0, 1.0), truth(None, 0.0, 0.0)],
            },
            visible: vec![visible("a", 10.0), visible("b", 40.0)],
        };
        let mut s = DetectorStats::new(vec![30.0, 70.0]);
        s.add(&sensed, Vec2::zeros(), 1);
        let t = s.table(&[0.9, 0.5], &[0.5, 1.0], 0.5);
        let num = |name: &str| match &t.columns.iter().find(|c| c.0 == name).unwrap().1 {
            crate::report::TableColumn::Number(v) => v.clone(),
            _ => panic!("{name}"),
        };
        assert_eq!(num("recall"), vec![1.0, 0.0]);
        assert_eq!(num("mean_error_m")[0], 1.0);
        assert_eq!(num("nees_mean")[0], 1.0);
        assert!(num("mean_error_m")[1].is_nan());
        assert_eq!(num("false_positives_per_sensor_frame")[0], 1.0);
        assert_eq!(num("recall_configured"), vec![0.9, 0.5]);
    }
}
