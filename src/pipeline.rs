//! One headless run: SUMO steps -> sensing -> graphs -> matching -> fusion ->
//! evaluation. The stages are called here in order with their own settings;
//! this module does no file IO (the caller writes the results).

use std::collections::{BTreeSet, HashMap};
use std::time::{Duration, Instant};

use crate::bridge::{BridgeError, Sumo};
use crate::config::{ConnectedSelection, PoseNoiseLevel, Settings};
use crate::eval::{self, EgoSide, ObjectEstimate, RowKey, Summary};
use crate::geometry::{Pose2, Vec2};
use crate::graph::{GraphError, SceneGraph};
use crate::matching::{self, MatchView, Matcher};
use crate::rng::{self, Purpose};
use crate::sensor::{self, Observation};
use crate::traffic::{StaticScene, TrafficFrame};

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    #[error(transparent)]
    Graph(#[from] GraphError),
    #[error(transparent)]
    Model(#[from] crate::matching::deep::LoadError),
    #[error("{0}")]
    Render(String),
    #[error("connected vehicle(s) {0:?} never appeared in the simulation before its end")]
    MissingConnectedVehicles(Vec<String>),
}

/// Progress reported once per simulation step.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub time_s: f64,
    pub end_s: f64,
    pub instances: usize,
}

/// One row of `objects.parquet`.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectRow {
    pub instance: usize,
    pub step: u64,
    pub time_s: f64,
    pub key: RowKey,
    pub estimate: ObjectEstimate,
}

/// Everything a run produced.
#[derive(Clone, Debug, Default)]
pub struct RunResults {
    pub summary: Summary,
    pub objects: Vec<ObjectRow>,
    pub n_instances: usize,
    pub n_steps: u64,
    pub sim_end_s: f64,
    /// Wall time spent inside the bridge's step calls.
    pub bridge_time: Duration,
    /// Road users read over all steps (for the per-object bridge cost).
    pub objects_read: u64,
    /// Wall time of the whole run.
    pub wall_time: Duration,
}

/// Whether a vehicle carries the camera rig.
fn is_connected(
    selection: &ConnectedSelection,
    sensor_seed: u64,
    obj: &crate::traffic::TrafficObject,
) -> bool {
    match selection {
        ConnectedSelection::Ids(ids) => ids.contains(&obj.id),
        ConnectedSelection::Penetration(p) => {
            obj.class.can_be_connected()
                && rng::unit(sensor_seed, Purpose::Penetration, &[rng::hash_str(&obj.id)]) < *p
        }
    }
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
    pub obs: Observation,
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
            &[step, self.id_hash, level.label as u64],
        );
        sensor::reported_pose(&self.obs.ego_pose_true, level, &mut s)
    }
}

impl<'a> Instance<'a> {
    /// What each vehicle of the pair knows at a pose-noise level: its
    /// detections, graph and GPS-reported pose.
    pub fn views(
        &self,
        sensor_seed: u64,
        level: &PoseNoiseLevel,
    ) -> (MatchView<'a>, MatchView<'a>) {
        let step = self.frame.step;
        let view = |e: &'a Ego| MatchView {
            detections: &e.obs.detections,
            graph: &e.graph,
            pose_reported: e.reported_pose(sensor_seed, step, level),
            pose_noise: *level,
        };
        (view(self.a), view(self.b))
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

/// Runs the scenario of `settings` from start to end and hands every
/// instance to `on_instance`, in a fixed order (by step, then by vehicle
/// ids).
pub fn simulate(
    settings: &Settings,
    mut progress: impl FnMut(Progress),
    mut on_instance: impl FnMut(&Instance) -> Result<(), RunError>,
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
            if is_connected(&settings.connected, settings.seeds.sensor, o) {
                seen_connected.insert(o.id.clone());
            }
        }
        if frame.time_s + eps >= next_sample_s {
            let egos = sense(settings, &scene, &frame)?;
            let mut found = 0;
            for i in 0..egos.len() {
                for j in (i + 1)..egos.len() {
                    if eval::covisible_pairs(&egos[i].obs, &egos[j].obs) == 0 {
                        continue;
                    }
                    on_instance(&Instance {
                        index: stats.n_instances,
                        scene: &scene,
                        frame: &frame,
                        a: &egos[i],
                        b: &egos[j],
                    })?;
                    stats.n_instances += 1;
                    found += 1;
                }
            }
            if found > 0 {
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
    if let ConnectedSelection::Ids(ids) = &settings.connected {
        let missing: Vec<String> = ids
            .iter()
            .filter(|i| !seen_connected.contains(*i))
            .cloned()
            .collect();
        if !missing.is_empty() {
            return Err(RunError::MissingConnectedVehicles(missing));
        }
    }
    Ok(stats)
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
        if !is_connected(&settings.connected, settings.seeds.sensor, o)
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
        let obs = sensor::observe(
            frame,
            scene,
            k,
            &settings.camera,
            &settings.sensor,
            &mut stream,
        );
        let positions: Vec<Vec2> = obs.detections.iter().map(|d| d.position_m).collect();
        let graph = SceneGraph::delaunay(&positions)?;
        egos.push(Ego {
            obs,
            graph,
            id_hash,
        });
    }
    egos.sort_by(|a, b| a.obs.ego_id.cmp(&b.obs.ego_id));
    Ok(egos)
}

/// Runs the scenario and evaluates every method, pose-noise level and
/// fusion variant on every instance.
pub fn run(settings: &Settings, progress: impl FnMut(Progress)) -> Result<RunResults, RunError> {
    let started = Instant::now();
    let matchers: Vec<Box<dyn Matcher>> = settings
        .matching
        .methods
        .iter()
        .map(|&m| matching::matcher_for(m, &settings.matching, settings.seeds.sensor))
        .collect::<Result<_, _>>()?;
    let mut results = RunResults::default();
    let stats = simulate(settings, progress, |inst| {
        evaluate_instance(settings, inst, &matchers, &mut results);
        Ok(())
    })?;
    results.n_instances = stats.n_instances;
    results.n_steps = stats.n_steps;
    results.sim_end_s = stats.sim_end_s;
    results.bridge_time = stats.bridge_time;
    results.objects_read = stats.objects_read;
    results.wall_time = started.elapsed();
    Ok(results)
}

/// Evaluates every method, pose-noise level and fusion variant on one
/// instance.
fn evaluate_instance(
    settings: &Settings,
    inst: &Instance,
    matchers: &[Box<dyn Matcher>],
    results: &mut RunResults,
) {
    let (a, b, frame) = (inst.a, inst.b, inst.frame);
    let truth_world_m: HashMap<&str, Vec2> = frame
        .objects
        .iter()
        .map(|o| (o.id.as_str(), o.pose.position_m()))
        .collect();
    for level in &settings.pose_noise {
        let (va, vb) = inst.views(settings.seeds.sensor, level);
        let (pa, pb) = (va.pose_reported, vb.pose_reported);
        for matcher in matchers {
            let matches = matcher.match_pair(&va, &vb);
            let counts = eval::count_pairs(&a.obs, &b.obs, &matches);
            let side_a = EgoSide {
                obs: &a.obs,
                pose_reported: pa,
            };
            let side_b = EgoSide {
                obs: &b.obs,
                pose_reported: pb,
            };
            for &variant in &settings.fusion.variants {
                let key = RowKey {
                    method: matcher.method(),
                    pose_noise: level.label,
                    fusion: variant,
                };
                let min = settings.fusion.align_min_matches;
                let est = eval::fuse_pair(
                    &side_a,
                    &side_b,
                    &matches,
                    level,
                    variant,
                    min,
                    &truth_world_m,
                );
                results.summary.record(key, counts, &est);
                results
                    .objects
                    .extend(est.into_iter().map(|estimate| ObjectRow {
                        instance: inst.index,
                        step: frame.step,
                        time_s: frame.time_s,
                        key,
                        estimate,
                    }));
            }
        }
    }
}
