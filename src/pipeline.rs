//! One headless run: SUMO steps -> sensing -> graphs -> matching -> fusion ->
//! evaluation. The stages are called here in order with their own settings;
//! this module does no file IO (the caller writes the results).

use std::collections::{BTreeSet, HashMap};
use std::time::{Duration, Instant};

use crate::bridge::{BridgeError, Sumo};
use crate::config::{ConnectedSelection, Settings};
use crate::eval::{self, EgoSide, ObjectEstimate, RowKey, Summary};
use crate::geometry::Vec2;
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

/// Runs the scenario of `settings` from start to end.
pub fn run(
    settings: &Settings,
    mut progress: impl FnMut(Progress),
) -> Result<RunResults, RunError> {
    let started = Instant::now();
    let sc = &settings.scenario;
    let mut sumo = Sumo::start(&sc.sumocfg, settings.seeds.traffic, sc.end_s)?;
    let scene = sumo.static_scene(&sc.junction)?;
    let matchers: Vec<Box<dyn Matcher>> = settings
        .matching
        .methods
        .iter()
        .map(|&m| matching::matcher_for(m, settings.matching.gate_chi2))
        .collect();

    let mut results = RunResults::default();
    let mut seen_connected: BTreeSet<String> = BTreeSet::new();
    let mut next_sample_s = f64::NEG_INFINITY;
    let eps = 1e-6;
    while sumo.time_s() + eps < sc.end_s {
        let t0 = Instant::now();
        let frame = sumo.step()?;
        results.bridge_time += t0.elapsed();
        results.n_steps += 1;
        results.objects_read += frame.objects.len() as u64;
        for o in &frame.objects {
            if is_connected(&settings.connected, settings.seeds.sensor, o) {
                seen_connected.insert(o.id.clone());
            }
        }
        if frame.time_s + eps >= next_sample_s {
            let n = evaluate_step(settings, &scene, &frame, &matchers, &mut results)?;
            if n > 0 {
                next_sample_s = frame.time_s + sc.sample_every_s;
            }
        }
        progress(Progress {
            time_s: frame.time_s,
            end_s: sc.end_s,
            instances: results.n_instances,
        });
    }
    results.sim_end_s = sumo.time_s();
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
    results.wall_time = started.elapsed();
    Ok(results)
}

/// A connected vehicle near the junction at this step, with what it sees.
struct Ego {
    obs: Observation,
    graph: SceneGraph,
    id_hash: u64,
}

/// Finds the instances of one step and evaluates every method, pose-noise
/// level and fusion variant on them. Returns the number of instances.
fn evaluate_step(
    settings: &Settings,
    scene: &StaticScene,
    frame: &TrafficFrame,
    matchers: &[Box<dyn Matcher>],
    results: &mut RunResults,
) -> Result<usize, RunError> {
    let sc = &settings.scenario;
    let mut egos: Vec<Ego> = Vec::new();
    for (k, o) in frame.objects.iter().enumerate() {
        if !is_connected(&settings.connected, settings.seeds.sensor, o)
            || (o.pose.position_m() - scene.junction_position_m).norm() > sc.radius_m
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
    if egos.len() < 2 {
        return Ok(0);
    }
    let truth_world_m: HashMap<&str, Vec2> = frame
        .objects
        .iter()
        .map(|o| (o.id.as_str(), o.pose.position_m()))
        .collect();

    let mut found = 0;
    for i in 0..egos.len() {
        for j in (i + 1)..egos.len() {
            let (a, b) = (&egos[i], &egos[j]);
            if eval::covisible_pairs(&a.obs, &b.obs) == 0 {
                continue;
            }
            found += 1;
            let instance = results.n_instances;
            results.n_instances += 1;
            for level in &settings.pose_noise {
                let reported = |e: &Ego| {
                    let mut s = rng::stream(
                        settings.seeds.sensor,
                        Purpose::PoseNoise,
                        &[frame.step, e.id_hash, level.label as u64],
                    );
                    sensor::reported_pose(&e.obs.ego_pose_true, level, &mut s)
                };
                let (pa, pb) = (reported(a), reported(b));
                let va = MatchView {
                    detections: &a.obs.detections,
                    graph: &a.graph,
                    pose_reported: pa,
                    pose_noise: *level,
                };
                let vb = MatchView {
                    detections: &b.obs.detections,
                    graph: &b.graph,
                    pose_reported: pb,
                    pose_noise: *level,
                };
                for matcher in matchers {
                    let matches = matcher.match_pair(&va, &vb);
                    let counts = eval::count_pairs(&a.obs, &b.obs, &matches);
                    let ab: Vec<(usize, usize)> = matches.iter().map(|c| (c.a, c.b)).collect();
                    let ba: Vec<(usize, usize)> = matches.iter().map(|c| (c.b, c.a)).collect();
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
                        let mut est = eval::fuse_for_ego(
                            &side_a,
                            &side_b,
                            &ab,
                            level,
                            variant,
                            min,
                            &truth_world_m,
                        );
                        est.extend(eval::fuse_for_ego(
                            &side_b,
                            &side_a,
                            &ba,
                            level,
                            variant,
                            min,
                            &truth_world_m,
                        ));
                        results.summary.record(key, counts, &est);
                        results
                            .objects
                            .extend(est.into_iter().map(|estimate| ObjectRow {
                                instance,
                                step: frame.step,
                                time_s: frame.time_s,
                                key,
                                estimate,
                            }));
                    }
                }
            }
        }
    }
    Ok(found)
}
