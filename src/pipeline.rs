//! One headless run: SUMO steps -> sensing -> graphs -> instances, each
//! handed out at every pose-noise level for [`evaluate`] to match, count
//! and fuse. The stages are called here in order with their own settings.
//! The only file this module reads is a deep method's weights, through
//! `io`; it writes nothing (the caller writes the results).

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use crate::bridge::{BridgeError, Sumo};
use crate::config::Settings;
use crate::evaluate::{self, PairAtLevel, Runner, Side};
use crate::geometry::{Pose2, Vec2};
use crate::graph::{GraphError, SceneGraph};
use crate::io::{self, WeightsError};
use crate::matching::deep::decision::Decision;
use crate::matching::{
    self, BuildError, DecisionChoice, DeepChoice, LambdaChoice, MatchView, Method,
};
use crate::report::{ObjectRow, RowKey, RunResults};
use crate::rng::{self, Purpose};
use crate::sensor::{self, ConnectedSelection, PoseNoiseLabel, PoseNoiseLevel, Sensed};
use crate::traffic::{StaticScene, TrafficFrame};

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    #[error(transparent)]
    Graph(#[from] GraphError),
    #[error(transparent)]
    Weights(#[from] WeightsError),
    #[error(transparent)]
    Build(#[from] BuildError),
    #[error("{0}")]
    Render(String),
    #[error("connected vehicle(s) {0:?} never appeared in the simulation before its end")]
    MissingConnectedVehicles(Vec<String>),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
}

/// Progress reported once per simulation step.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub time_s: f64,
    pub end_s: f64,
    pub instances: usize,
}

/// Counters of one simulation.
#[derive(Clone, Debug, Default)]
pub struct SimStats {
    pub n_instances: usize,
    pub n_steps: u64,
    pub sim_end_s: f64,
    /// Wall time spent inside the bridge's step calls.
    pub bridge_time: Duration,
    /// Road users read over all steps (for the per-object bridge cost).
    pub objects_read: u64,
}

/// A connected vehicle near the junction at one step, with what it sees.
pub struct Ego {
    pub sensed: Sensed,
    pub graph: SceneGraph,
    id_hash: u64,
}

impl Ego {
    /// The pose this vehicle's GPS reports at `step` at a noise level (its
    /// own seeded stream per step, vehicle and level).
    pub fn reported_pose(&self, sensor_seed: u64, step: u64, level: &PoseNoiseLevel) -> Pose2 {
        let mut s = rng::stream(
            sensor_seed,
            Purpose::PoseNoise,
            &[step, self.id_hash, level.label.stream_code()],
        );
        sensor::reported_pose(&self.sensed.truth.ego_pose, level, &mut s)
    }
}

/// One evaluation instance: a step and a pair of connected vehicles, both
/// near the junction, that detect at least one common object.
pub struct Instance<'a> {
    /// Running index within the simulation.
    pub index: usize,
    pub scene: &'a StaticScene,
    pub frame: &'a TrafficFrame,
    /// The pair, ordered by vehicle id.
    pub a: &'a Ego,
    pub b: &'a Ego,
}

impl<'a> Instance<'a> {
    /// The instance at a pose-noise level: each vehicle's detections, graph
    /// and GPS-reported pose, with the truth beside them.
    pub fn at_level(&self, sensor_seed: u64, level: &PoseNoiseLevel) -> PairAtLevel<'a> {
        let step = self.frame.step;
        let side = |e: &'a Ego| Side {
            view: MatchView {
                detections: &e.sensed.observation.detections,
                graph: &e.graph,
                pose_reported: e.reported_pose(sensor_seed, step, level),
                pose_noise: *level,
            },
            obs: &e.sensed.observation,
            truth: &e.sensed.truth,
        };
        PairAtLevel {
            first: side(self.a),
            second: side(self.b),
            level: *level,
        }
    }
}

/// Runs the scenario of `settings` from start to end and hands every
/// instance to `on_instance`, in a fixed order (by step, then by vehicle
/// ids).
pub fn simulate(
    settings: &Settings,
    progress: impl FnMut(Progress),
    mut on_instance: impl FnMut(&Instance) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    simulate_frames(settings, progress, |instances| {
        instances.iter().try_for_each(&mut on_instance)
    })
}

/// Runs the scenario of `settings` from start to end and hands the
/// instances of every sampled step to `on_frame` at once (never an empty
/// list), in a fixed order (by step, then by vehicle ids).
pub fn simulate_frames(
    settings: &Settings,
    mut progress: impl FnMut(Progress),
    mut on_frame: impl FnMut(&[Instance]) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    let sc = &settings.scenario;
    let mut sumo = Sumo::start(&sc.sumocfg, settings.seeds.traffic, sc.end_s)?;
    let scene = sumo.static_scene(&sc.junction)?;
    let mut stats = SimStats::default();
    let mut seen_connected: BTreeSet<String> = BTreeSet::new();
    let mut next_sample_s = f64::NEG_INFINITY;
    let eps = 1e-6;
    while sumo.time_s() + eps < sc.end_s {
        let t0 = Instant::now();
        let frame = sumo.step()?;
        stats.bridge_time += t0.elapsed();
        stats.n_steps += 1;
        stats.objects_read += frame.objects.len() as u64;
        for o in &frame.objects {
            if settings.connected.carries_rig(settings.seeds.sensor, o) {
                seen_connected.insert(o.id.clone());
            }
        }
        if frame.time_s + eps >= next_sample_s {
            let egos = sense(settings, &scene, &frame)?;
            let instances = frame_instances(&scene, &frame, &egos, stats.n_instances);
            if !instances.is_empty() {
                on_frame(&instances)?;
                stats.n_instances += instances.len();
                next_sample_s = frame.time_s + sc.sample_every_s;
            }
        }
        progress(Progress {
            time_s: frame.time_s,
            end_s: sc.end_s,
            instances: stats.n_instances,
        });
    }
    stats.sim_end_s = sumo.time_s();
    sumo.close()?;
    check_connected_appeared(&settings.connected, &seen_connected)?;
    Ok(stats)
}

/// The instances of one step: every pair of `egos` (sorted by id) whose
/// cameras detect a common object, numbered from `first_index`.
fn frame_instances<'a>(
    scene: &'a StaticScene,
    frame: &'a TrafficFrame,
    egos: &'a [Ego],
    first_index: usize,
) -> Vec<Instance<'a>> {
    let mut out = Vec::new();
    for (i, a) in egos.iter().enumerate() {
        for b in &egos[i + 1..] {
            if evaluate::share_a_detected_object(&a.sensed.truth, &b.sensed.truth) {
                out.push(Instance {
                    index: first_index + out.len(),
                    scene,
                    frame,
                    a,
                    b,
                });
            }
        }
    }
    out
}

/// Named connected vehicles must all have appeared.
fn check_connected_appeared(
    selection: &ConnectedSelection,
    seen: &BTreeSet<String>,
) -> Result<(), RunError> {
    if let ConnectedSelection::Ids(ids) = selection {
        let missing: Vec<String> = ids.iter().filter(|i| !seen.contains(*i)).cloned().collect();
        if !missing.is_empty() {
            return Err(RunError::MissingConnectedVehicles(missing));
        }
    }
    Ok(())
}

/// Observations and graphs of the connected vehicles near the junction,
/// sorted by vehicle id.
fn sense(
    settings: &Settings,
    scene: &StaticScene,
    frame: &TrafficFrame,
) -> Result<Vec<Ego>, RunError> {
    let mut egos: Vec<Ego> = Vec::new();
    for (k, o) in frame.objects.iter().enumerate() {
        if !settings.connected.carries_rig(settings.seeds.sensor, o)
            || (o.pose.position_m() - scene.junction_position_m).norm() > settings.scenario.radius_m
        {
            continue;
        }
        let id_hash = rng::hash_str(&o.id);
        let mut stream = rng::stream(
            settings.seeds.sensor,
            Purpose::Detections,
            &[frame.step, id_hash],
        );
        let (camera, sensor) = (&settings.camera, &settings.sensor);
        let mut sensed = sensor::observe(frame, scene, k, camera, sensor, &mut stream);
        if settings.matching.sender_as_node {
            sensed.add_sender(o);
        }
        sensed.shuffle(&mut rng::stream(
            settings.seeds.sensor,
            Purpose::NodeOrder,
            &[frame.step, id_hash],
        ));
        let positions: Vec<Vec2> = sensed
            .observation
            .detections
            .iter()
            .map(|d| d.position_m)
            .collect();
        let graph = SceneGraph::delaunay(&positions)?;
        egos.push(Ego {
            sensed,
            graph,
            id_hash,
        });
    }
    egos.sort_by(|a, b| {
        a.sensed
            .observation
            .ego_id
            .cmp(&b.sensed.observation.ego_id)
    });
    Ok(egos)
}

/// How a deep method decides: its entropy threshold and decision rule as
/// configured, or as `coid train` chose them on the validation runs, and
/// the calibration temperature fitted there (recorded beside the weights;
/// 1 when the models folder records none).
pub fn choice_for(settings: &Settings, method: Method) -> Result<DeepChoice, RunError> {
    let m = &settings.matching;
    let validated = match (m.lambda, m.decision) {
        // Only the temperature is read: without it, the probabilities as
        // they are.
        (LambdaChoice::Fixed(_), DecisionChoice::Fixed(_)) => {
            io::read_validated(&m.models_dir, method).ok()
        }
        _ => Some(io::read_validated(&m.models_dir, method)?),
    };
    let missing = |what: &str| {
        RunError::Weights(WeightsError {
            method: method.as_str(),
            path: m.models_dir.join(format!("{}.toml", method.as_str())),
            reason: format!(
                "no validated_{what}: set [matching] {what}, or run `coid train --validate-only`"
            ),
        })
    };
    let lambda = match m.lambda {
        LambdaChoice::Fixed(v) => v,
        LambdaChoice::Validated => validated
            .and_then(|v| v.lambda)
            .ok_or_else(|| missing("lambda"))?,
    };
    let decision = match m.decision {
        DecisionChoice::Fixed(d) => d,
        DecisionChoice::Validated => validated
            .and_then(|v| v.decision)
            .ok_or_else(|| missing("decision"))?,
    };
    let temperature = validated.and_then(|v| v.temperature).unwrap_or(1.0);
    Ok(DeepChoice {
        lambda,
        decision,
        temperature,
    })
}

/// The choice of every deep method among `methods` ([`choice_for`]).
pub fn choices(
    settings: &Settings,
    methods: &[Method],
) -> Result<BTreeMap<Method, DeepChoice>, RunError> {
    methods
        .iter()
        .filter(|m| matching::deep::variant(**m).is_some())
        .map(|&m| Ok((m, choice_for(settings, m)?)))
        .collect()
}

/// The lambda of every deep method among `methods`.
pub fn lambdas(settings: &Settings, methods: &[Method]) -> Result<BTreeMap<Method, f64>, RunError> {
    Ok(choices(settings, methods)?
        .into_iter()
        .map(|(m, c)| (m, c.lambda))
        .collect())
}

/// How `method` runs with `settings`: deep methods get their weights from
/// `[matching] models_dir` and their lambda and decision rule
/// ([`choice_for`]); MC-dropout masks are seeded with the sensor seed.
pub fn runner(settings: &Settings, method: Method) -> Result<Runner, RunError> {
    if method == Method::Oracle {
        return Ok(Runner::Oracle);
    }
    let m = &settings.matching;
    let (weights, choice) = if matching::deep::variant(method).is_some() {
        (
            Some(io::read_weights(&m.models_dir, method)?),
            choice_for(settings, method)?,
        )
    } else {
        (None, NO_CHOICE)
    };
    let matcher = matching::build(method, m, choice, settings.seeds.sensor, weights.as_deref())
        .map_err(|e| match e {
            BuildError::BadWeights {
                method: label,
                reason,
            } => RunError::Weights(WeightsError {
                method: label,
                path: io::weights_path(&m.models_dir, method),
                reason,
            }),
            other => RunError::Build(other),
        })?;
    Ok(Runner::Matcher(matcher))
}

/// What a method that is not deep is built with (it reads neither).
const NO_CHOICE: DeepChoice = DeepChoice {
    lambda: f64::NAN,
    decision: Decision::Assignment,
    temperature: 1.0,
};

/// The runners of `methods`, in order.
pub fn runners(settings: &Settings, methods: &[Method]) -> Result<Vec<Runner>, RunError> {
    methods.iter().map(|&m| runner(settings, m)).collect()
}

/// Runs the scenario and evaluates every configured method, pose-noise
/// level and fusion variant on every instance, frame by frame
/// ([`evaluate::evaluate_frame`], with `[matching] multi_vehicle`).
pub fn run(settings: &Settings, progress: impl FnMut(Progress)) -> Result<RunResults, RunError> {
    let started = Instant::now();
    let runners = runners(settings, &settings.matching.methods)?;
    let mut results = RunResults::default();
    let stats = evaluate_frames(settings, &runners, progress, |instances, _, level, f| {
        record_frame(&mut results, instances, level, f);
    })?;
    results.n_instances = stats.n_instances;
    results.n_steps = stats.n_steps;
    results.sim_end_s = stats.sim_end_s;
    results.bridge_time = stats.bridge_time;
    results.objects_read = stats.objects_read;
    results.wall_time = started.elapsed();
    Ok(results)
}

/// Runs the scenario and hands every frame's evaluation to `on_eval`: for
/// each sampled step, each pose-noise level and each runner in order, the
/// step's instances, their pairs at that level, the level, and what
/// [`evaluate::evaluate_frame`] made of them (with `[matching]
/// multi_vehicle`).
pub fn evaluate_frames(
    settings: &Settings,
    runners: &[Runner],
    progress: impl FnMut(Progress),
    mut on_eval: impl FnMut(&[Instance], &[PairAtLevel], PoseNoiseLabel, evaluate::FrameEval),
) -> Result<SimStats, RunError> {
    simulate_frames(settings, progress, |instances| {
        for level in &settings.pose_noise {
            let pairs: Vec<PairAtLevel> = instances
                .iter()
                .map(|i| i.at_level(settings.seeds.sensor, level))
                .collect();
            for runner in runners {
                let f = evaluate::evaluate_frame(
                    &pairs,
                    runner,
                    &settings.fusion,
                    settings.matching.multi_vehicle,
                );
                on_eval(instances, &pairs, level.label, f);
            }
        }
        Ok(())
    })
}

/// Adds one method's evaluation of a frame at one level to `results`.
fn record_frame(
    results: &mut RunResults,
    instances: &[Instance],
    pose_noise: PoseNoiseLabel,
    f: evaluate::FrameEval,
) {
    for (inst, e) in instances.iter().zip(f.pairs) {
        for (fusion, est) in e.fused {
            let key = RowKey {
                method: e.method,
                pose_noise,
                fusion,
            };
            results.summary.record(key, e.counts, &est);
            results
                .objects
                .extend(est.into_iter().map(|estimate| ObjectRow {
                    instance: inst.index,
                    step: inst.frame.step,
                    time_s: inst.frame.time_s,
                    key,
                    estimate,
                }));
        }
    }
    for (fusion, views) in &f.views {
        let key = RowKey {
            method: f.method,
            pose_noise,
            fusion: *fusion,
        };
        results.summary.record_views(key, views);
    }
    results
        .summary
        .record_consistency(f.method, pose_noise, f.consistency);
}
