//! Validation of the stage sections: `[scenario]`, `[connected]`,
//! `[camera]`, `[sensor]`, `[pose_noise]`, `[matching]`, `[fusion]`, and
//! the whole raw file into [`Settings`] (the learning and V2X sections in
//! their own files).

use std::collections::BTreeSet;
use std::path::Path;

use super::check::{Checker, field, num};
use super::raw::{
    RawCamera, RawConfig, RawConnected, RawFusion, RawLambda, RawMatching, RawPoseNoise, RawRate,
    RawScenario, RawSensor,
};
use super::{ConfigError, Settings};
use crate::fusion::FusionSettings;
use crate::matching::deep::decision::Decision;
use crate::matching::{DecisionChoice, LambdaChoice, MatchingSettings, Method};
use crate::rng::Seeds;
use crate::sensor::{
    CameraSettings, ConnectedSelection, LinkSettings, PoseNoiseLabel, PoseNoiseLevel,
    SensorSettings,
};
use crate::traffic::ScenarioSettings;

/// More cameras per vehicle than this are refused (each one's detections
/// are nodes of every graph).
const MAX_CAMERAS: usize = 16;

/// A GNSS position error's standard deviation at most (metres).
const MAX_POSITION_SIGMA_M: f64 = 1000.0;

/// More MC-dropout samples than this are refused: every sample holds the
/// network's activations of both graphs (the paper uses T = 20 and sweeps
/// 10-100).
const MAX_MC_SAMPLES: usize = 1000;

/// More false positives per camera and frame than this are refused: each
/// is a node of every graph (and a sample of memory per step).
const MAX_FALSE_POSITIVES_PER_FRAME: f64 = 100.0;

pub(super) fn validate(
    raw: RawConfig,
    path: &Path,
    stated: &BTreeSet<String>,
) -> Result<Settings, ConfigError> {
    let c = Checker { path, stated };
    c.traffic_seed("seeds.traffic", raw.seeds.traffic)?;
    let (train, eval) = super::learning::train_and_eval(&c, raw.train, raw.eval)?;
    Ok(Settings {
        source: path.to_owned(),
        scenario: scenario(&c, raw.scenario)?,
        link: link(&c, &raw.connected)?,
        connected: connected(&c, raw.connected)?,
        seeds: Seeds {
            traffic: raw.seeds.traffic,
            sensor: raw.seeds.sensor,
        },
        camera: camera(&c, raw.camera)?,
        sensor: sensor(&c, raw.sensor)?,
        pose_noise: pose_noise(&c, raw.pose_noise)?,
        matching: matching(&c, raw.matching)?,
        fusion: fusion(&c, raw.fusion)?,
        train,
        eval,
        v2x: super::v2x::v2x(&c, raw.v2x)?,
        detector: super::detector::detector(&c, raw.detector)?,
        appearance: super::appearance::appearance(&c, raw.appearance)?,
        dataset: None,
    })
}

fn scenario(c: &Checker, s: RawScenario) -> Result<ScenarioSettings, ConfigError> {
    let sumocfg = c.resolve(&s.sumocfg);
    if sumocfg.is_dir() {
        return Err(c.invalid(
            "scenario.sumocfg",
            format!(
                "{} is a folder, not a SUMO configuration file (.sumocfg)",
                sumocfg.display()
            ),
        ));
    }
    if !sumocfg.is_file() {
        return Err(c.invalid(
            "scenario.sumocfg",
            format!("no such file: {}", sumocfg.display()),
        ));
    }
    let sumocfg = sumocfg.canonicalize().map_err(|e| {
        c.invalid(
            "scenario.sumocfg",
            format!("cannot resolve {}: {e}", sumocfg.display()),
        )
    })?;
    if s.junction.is_empty() {
        return Err(c.invalid(
            "scenario.junction",
            "missing: the junction id to study".into(),
        ));
    }
    c.positive(field!("scenario", s.end_s))?;
    c.positive(field!("scenario", s.radius_m))?;
    c.positive(field!("scenario", s.sample_every_s))?;
    Ok(ScenarioSettings {
        sumocfg,
        junction: s.junction,
        end_s: s.end_s,
        radius_m: s.radius_m,
        sample_every_s: s.sample_every_s,
    })
}

fn link(c: &Checker, raw: &RawConnected) -> Result<LinkSettings, ConfigError> {
    if let Some(r) = raw.comm_range_m {
        c.positive(("connected.comm_range_m", r))?;
    }
    if raw.max_peers == Some(0) {
        return Err(c.invalid(
            "connected.max_peers",
            "must be at least 1 (leave it out for no limit)".into(),
        ));
    }
    Ok(LinkSettings {
        comm_range_m: raw.comm_range_m,
        max_peers: raw.max_peers,
    })
}

fn connected(c: &Checker, raw: RawConnected) -> Result<ConnectedSelection, ConfigError> {
    match (raw.ids, raw.penetration) {
        (Some(_), Some(_)) => Err(c.invalid(
            "connected",
            "give either `ids` or `penetration`, not both".into(),
        )),
        (None, None) => Err(c.invalid(
            "connected",
            "give `ids` (at least two vehicle ids) or `penetration`".into(),
        )),
        (Some(ids), None) => {
            if ids.len() < 2 {
                return Err(c.invalid(
                    "connected.ids",
                    format!("need at least two connected vehicles, got {}", ids.len()),
                ));
            }
            let mut sorted = ids.clone();
            sorted.sort();
            sorted.dedup();
            if sorted.len() != ids.len() {
                return Err(c.invalid("connected.ids", "ids repeat".into()));
            }
            Ok(ConnectedSelection::Ids(ids))
        }
        (None, Some(p)) => {
            if !(p > 0.0 && p <= 1.0) {
                return Err(c.invalid(
                    "connected.penetration",
                    format!("must be in (0, 1], got {}", num(p)),
                ));
            }
            Ok(ConnectedSelection::Penetration(p))
        }
    }
}

fn camera(c: &Checker, raw: RawCamera) -> Result<CameraSettings, ConfigError> {
    if !(raw.fov_deg > 0.0 && raw.fov_deg < 180.0) {
        return Err(c.invalid(
            "camera.fov_deg",
            format!("must be in (0, 180), got {}", num(raw.fov_deg)),
        ));
    }
    c.positive(field!("camera", raw.range_m))?;
    c.positive(field!("camera", raw.height_m))?;
    let yaws = &raw.yaw_offsets_deg;
    if yaws.is_empty() || yaws.iter().any(|y| !y.is_finite()) {
        return Err(c.invalid(
            "camera.yaw_offsets_deg",
            "need one finite yaw per camera".into(),
        ));
    }
    if yaws.len() > MAX_CAMERAS {
        return Err(c.invalid(
            "camera.yaw_offsets_deg",
            format!("at most {MAX_CAMERAS} cameras, got {}", yaws.len()),
        ));
    }
    // The same direction twice (also as 0 and 360) is one camera counted
    // twice: every detection doubled.
    for (k, y) in yaws.iter().enumerate() {
        let same = |o: &f64| ((y - o).rem_euclid(360.0)).min((o - y).rem_euclid(360.0)) < 1e-9;
        if let Some(o) = yaws[..k].iter().find(|o| same(o)) {
            return Err(c.invalid(
                "camera.yaw_offsets_deg",
                format!(
                    "{} and {} deg are the same camera (one camera per direction)",
                    num(*o),
                    num(*y)
                ),
            ));
        }
    }
    Ok(CameraSettings {
        fov_rad: raw.fov_deg.to_radians(),
        range_m: raw.range_m,
        height_m: raw.height_m,
        yaw_offsets_rad: raw.yaw_offsets_deg.iter().map(|y| y.to_radians()).collect(),
    })
}

fn sensor(c: &Checker, s: RawSensor) -> Result<SensorSettings, ConfigError> {
    c.fraction(field!("sensor", s.min_visible_fraction))?;
    c.fraction(field!("sensor", s.aim_height_fraction))?;
    c.fraction(field!("sensor", s.miss_prob_base))?;
    c.fraction(field!("sensor", s.miss_prob_at_max_range))?;
    c.fraction(field!("sensor", s.miss_prob_occlusion))?;
    c.fraction(field!("sensor", s.class_confusion_prob))?;
    c.fraction(field!("sensor", s.lighting_spread))?;
    c.non_negative(field!("sensor", s.range_sigma_base_m))?;
    c.non_negative(field!("sensor", s.range_sigma_per_m))?;
    c.non_negative(field!("sensor", s.bearing_sigma_base_deg))?;
    c.non_negative(field!("sensor", s.bearing_sigma_per_m_deg))?;
    c.non_negative(field!("sensor", s.false_positives_per_frame))?;
    if s.false_positives_per_frame > MAX_FALSE_POSITIVES_PER_FRAME {
        return Err(c.invalid(
            "sensor.false_positives_per_frame",
            format!(
                "at most {MAX_FALSE_POSITIVES_PER_FRAME} per camera and frame, got {}",
                num(s.false_positives_per_frame)
            ),
        ));
    }
    c.non_negative(field!("sensor", s.colour_sigma))?;
    c.non_negative(field!("sensor", s.size_sigma_fraction))?;
    if s.range_sigma_base_m + s.bearing_sigma_base_deg <= 0.0 {
        return Err(c.invalid(
            "sensor.range_sigma_base_m",
            "range and bearing noise cannot both be zero at zero distance (the covariance would be singular)".into(),
        ));
    }
    Ok(SensorSettings {
        min_visible_fraction: s.min_visible_fraction,
        aim_height_fraction: s.aim_height_fraction,
        range_sigma_base_m: s.range_sigma_base_m,
        range_sigma_per_m: s.range_sigma_per_m,
        bearing_sigma_base_rad: s.bearing_sigma_base_deg.to_radians(),
        bearing_sigma_per_m_rad: s.bearing_sigma_per_m_deg.to_radians(),
        miss_prob_base: s.miss_prob_base,
        miss_prob_at_max_range: s.miss_prob_at_max_range,
        miss_prob_occlusion: s.miss_prob_occlusion,
        false_positives_per_frame: s.false_positives_per_frame,
        class_confusion_prob: s.class_confusion_prob,
        colour_sigma: s.colour_sigma,
        lighting_spread: s.lighting_spread,
        size_sigma_fraction: s.size_sigma_fraction,
        unset_colours: s.unset_colours,
        boxes: c.box_errors(
            "sensor",
            [s.heading_sigma_deg, s.heading_flip_prob, s.speed_sigma_mps],
        )?,
    })
}

/// The longest GNSS correlation time a level takes (s), as `[v2x]
/// gnss_correlation_s`.
const MAX_CORRELATION_S: f64 = 1e6;

fn pose_noise(c: &Checker, p: RawPoseNoise) -> Result<Vec<PoseNoiseLevel>, ConfigError> {
    if p.levels.is_empty() {
        return Err(c.invalid("pose_noise.levels", "need at least one level".into()));
    }
    if p.defined.contains_key("none") {
        return Err(c.invalid(
            "pose_noise",
            "level none is exact self-localisation and takes no sigmas: give the level a name \
             of its own"
                .into(),
        ));
    }
    c.distinct("pose_noise.levels", p.levels)?
        .into_iter()
        .map(|label| {
            let (sigma_m, sigma_deg, correlation_s) = match p.defined.get(label.as_str()) {
                _ if label == PoseNoiseLabel::NONE => (0.0, 0.0, None),
                Some(l) => (l.position_sigma_m, l.heading_sigma_deg, l.correlation_s),
                None => {
                    return Err(c.invalid(
                        "pose_noise",
                        format!(
                            "level {0} has no sigmas: add {0:?} = {{ position_sigma_m = ..., \
                             heading_sigma_deg = ... }} under [pose_noise]",
                            label.as_str()
                        ),
                    ));
                }
            };
            // Beyond these a receiver knows nothing of where it is, and
            // squared sigmas stay far from overflowing.
            let ok = |v: f64, hi: f64| (0.0..=hi).contains(&v);
            if !(ok(sigma_m, MAX_POSITION_SIGMA_M) && ok(sigma_deg, 180.0)) {
                return Err(c.invalid(
                    "pose_noise",
                    format!(
                        "level {}: position_sigma_m must be in [0, {MAX_POSITION_SIGMA_M}] and \
                         heading_sigma_deg in [0, 180], got {} m and {} deg",
                        label.as_str(),
                        num(sigma_m),
                        num(sigma_deg)
                    ),
                ));
            }
            if let Some(tau) = correlation_s.filter(|t| !(0.0..=MAX_CORRELATION_S).contains(t)) {
                return Err(c.invalid(
                    "pose_noise",
                    format!(
                        "level {}: correlation_s must be in [0, {MAX_CORRELATION_S}] s, got {}",
                        label.as_str(),
                        num(tau)
                    ),
                ));
            }
            Ok(PoseNoiseLevel {
                label,
                position_sigma_m: sigma_m,
                heading_sigma_rad: sigma_deg.to_radians(),
                correlation_s,
            })
        })
        .collect()
}

/// The dropout rate of MC dropout at inference: the trained one, or a
/// number in [0, 0.95].
fn mc_dropout(c: &Checker, raw: RawRate) -> Result<Option<f64>, ConfigError> {
    match raw {
        RawRate::Word(w) if w == "trained" => Ok(None),
        RawRate::Value(v) => mc_rate(c, v).map(Some),
        RawRate::Word(w) => Err(c.invalid(
            "matching.mc_dropout",
            format!("must be a rate in [0, 0.95] or \"trained\", got \"{w}\""),
        )),
    }
}

/// A dropout rate at inference in [0, 0.95].
fn mc_rate(c: &Checker, v: f64) -> Result<f64, ConfigError> {
    if (0.0..=0.95).contains(&v) {
        return Ok(v);
    }
    Err(c.invalid(
        "matching.mc_dropout",
        format!("must be a rate in [0, 0.95] or \"trained\", got {}", num(v)),
    ))
}

/// A number of MC-dropout samples at inference, 1 to [`MAX_MC_SAMPLES`].
fn mc_samples(c: &Checker, n: usize) -> Result<usize, ConfigError> {
    if (1..=MAX_MC_SAMPLES).contains(&n) {
        return Ok(n);
    }
    Err(c.invalid(
        "matching.mc_samples",
        format!("must be 1 to {MAX_MC_SAMPLES} samples, got {n}"),
    ))
}

impl Settings {
    /// These settings inferring with `samples` MC-dropout samples at the
    /// dropout `rate` (`None`: as trained), checked as `[matching]
    /// mc_samples` and `mc_dropout` are: a point of a sweep is a
    /// configuration of its own, never an edit of a validated one.
    pub fn with_inference(&self, samples: usize, rate: Option<f64>) -> Result<Self, ConfigError> {
        let stated = BTreeSet::new();
        let c = Checker {
            path: &self.source,
            stated: &stated,
        };
        let mut s = self.clone();
        s.matching.mc_samples = mc_samples(&c, samples)?;
        s.matching.mc_dropout = rate.map(|v| mc_rate(&c, v)).transpose()?;
        Ok(s)
    }
}

fn matching(c: &Checker, m: RawMatching) -> Result<MatchingSettings, ConfigError> {
    if m.methods.is_empty() {
        return Err(c.invalid("matching.methods", "need at least one method".into()));
    }
    if m.methods.contains(&Method::External) {
        return Err(c.invalid(
            "matching.methods",
            "'external' correspondences come from a file: score them with `coid score --matches FILE`".into(),
        ));
    }
    c.positive(field!("matching", m.gate_chi2))?;
    mc_samples(c, m.mc_samples)?;
    let lambda = match m.lambda {
        RawLambda::Word(w) if w == "validated" => LambdaChoice::Validated,
        RawLambda::Word(w) if w == "none" => LambdaChoice::Fixed(f64::INFINITY),
        RawLambda::Value(v) if (0.0..=1.0).contains(&v) => LambdaChoice::Fixed(v),
        RawLambda::Value(v) => {
            return Err(c.invalid(
                "matching.lambda",
                format!("must be in [0, 1] (binary entropy in bits), got {}", num(v)),
            ));
        }
        RawLambda::Word(w) => {
            return Err(c.invalid(
                "matching.lambda",
                format!("must be a number in [0, 1], \"none\" or \"validated\", got \"{w}\""),
            ));
        }
    };
    let decision = match m.decision.as_str() {
        "validated" => DecisionChoice::Validated,
        word => DecisionChoice::Fixed(crate::label::parse::<Decision>("decision", word).map_err(
            |e| {
                c.invalid(
                    "matching.decision",
                    format!("must be \"validated\" or a rule: {e}"),
                )
            },
        )?),
    };
    if m.rematch > MAX_REMATCH {
        return Err(c.invalid(
            "matching.rematch",
            format!("at most {MAX_REMATCH} rounds, got {}", m.rematch),
        ));
    }
    Ok(MatchingSettings {
        methods: c.distinct("matching.methods", m.methods)?,
        baselines: m.baselines,
        gate_chi2: m.gate_chi2,
        models_dir: c.resolve(&m.models_dir),
        mc_samples: m.mc_samples,
        dropout_masks: m.dropout_masks,
        mc_dropout: mc_dropout(c, m.mc_dropout)?,
        lambda,
        decision,
        uncertainty: m.uncertainty,
        sender_as_node: m.sender_as_node,
        multi_vehicle: m.multi_vehicle,
        rematch: m.rematch,
        indicators: m.indicators,
    })
}

fn fusion(c: &Checker, f: RawFusion) -> Result<FusionSettings, ConfigError> {
    if f.variants.is_empty() {
        return Err(c.invalid("fusion.variants", "need at least one variant".into()));
    }
    if f.align_min_matches < 2 {
        return Err(c.invalid(
            "fusion.align_min_matches",
            "a rigid alignment needs at least 2 matched objects".into(),
        ));
    }
    Ok(FusionSettings {
        variants: c.distinct("fusion.variants", f.variants)?,
        align_min_matches: f.align_min_matches,
    })
}

/// More rounds of match-align-rematch than this change nothing but the
/// run time (the alignment settles after two or three).
const MAX_REMATCH: usize = 10;
