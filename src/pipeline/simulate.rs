//! The simulation loop: SUMO steps, the connected vehicles near the
//! junction sense, and the pairs that are linked and share an object
//! become instances (with `[v2x] mode = "cpm"`, the receptions do), handed
//! out one at a time, per step, or as [`Step`]s that own them.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use super::instance::{Instance, InstanceSide, ViewSource};
use super::{Progress, RunError, SimStats, receptions};
use crate::bridge::Sumo;
use crate::config::Settings;
use crate::evaluate;
use crate::geometry::Vec2;
use crate::rng::{self, Purpose};
use crate::sensor::{self, ConnectedSelection, LinkSettings};
use crate::traffic::{StaticScene, TrafficFrame};
use crate::v2x::V2xMode;

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
    progress: impl FnMut(Progress),
    mut on_frame: impl FnMut(&[Instance]) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    simulate_steps(settings, progress, |step| on_frame(&step.instances()))
}

/// A sampled step with at least one instance, owning what its instances
/// borrow, so that it can be evaluated on another thread.
pub struct Step {
    scene: Arc<StaticScene>,
    frame: TrafficFrame,
    sides: Vec<InstanceSide>,
    /// The instances' sides, as indices into `sides` (ordered by id).
    pairs: Vec<(usize, usize)>,
    /// The running index of the step's first instance.
    first_index: usize,
}

impl Step {
    /// The step's instances, in order.
    pub fn instances(&self) -> Vec<Instance<'_>> {
        self.pairs
            .iter()
            .enumerate()
            .map(|(k, &(a, b))| Instance {
                index: self.first_index + k,
                scene: &self.scene,
                frame: &self.frame,
                a: &self.sides[a],
                b: &self.sides[b],
            })
            .collect()
    }
}

/// Runs the scenario of `settings` from start to end and hands every
/// sampled step that has an instance to `on_step`, in order.
pub fn simulate_steps(
    settings: &Settings,
    mut progress: impl FnMut(Progress),
    mut on_step: impl FnMut(Step) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    let sc = &settings.scenario;
    let cpm = settings.v2x.mode == V2xMode::Cpm;
    let step_length_s = cpm.then_some(settings.v2x.step_length_s);
    let mut sumo = Sumo::start(&sc.sumocfg, settings.seeds.traffic, sc.end_s, step_length_s)?;
    let scene = Arc::new(sumo.static_scene(&sc.junction)?);
    let mut receptions = cpm.then(receptions::Receptions::default);
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
        note_connected(settings, &frame, &mut seen_connected);
        let time_s = frame.time_s;
        let sample = time_s + eps >= next_sample_s;
        let instances = match receptions.as_mut() {
            Some(r) => {
                let vehicles = sense(settings, &scene, &frame)?;
                Some(r.step(settings, &frame, &vehicles, sample)?)
            }
            None if sample => {
                let vehicles = sense(settings, &scene, &frame)?;
                let pairs = instance_pairs(&vehicles, &settings.link);
                Some((vehicles, pairs))
            }
            None => None,
        };
        if let Some((sides, pairs)) = instances
            && !pairs.is_empty()
        {
            let n = pairs.len();
            on_step(Step {
                scene: Arc::clone(&scene),
                frame,
                sides,
                pairs,
                first_index: stats.n_instances,
            })?;
            stats.n_instances += n;
            next_sample_s = time_s + sc.sample_every_s;
        }
        progress(Progress {
            time_s,
            end_s: sc.end_s,
            instances: stats.n_instances,
        });
    }
    stats.sim_end_s = sumo.time_s();
    sumo.close()?;
    check_connected_appeared(&settings.connected, &seen_connected)?;
    Ok(stats)
}

/// The instances of one step: every pair of `sides` (sorted by id) whose
/// cameras detect a common object and that `link` lets talk to each other.
fn instance_pairs(sides: &[InstanceSide], link: &LinkSettings) -> Vec<(usize, usize)> {
    let positions: Vec<Vec2> = sides
        .iter()
        .map(|e| e.sensed.truth.ego_pose.position_m())
        .collect();
    let links = link.links(&positions);
    let mut out = Vec::new();
    for (i, a) in sides.iter().enumerate() {
        for (j, b) in sides.iter().enumerate().skip(i + 1) {
            if links.linked(i, j)
                && evaluate::share_a_detected_object(&a.sensed.truth, &b.sensed.truth)
            {
                out.push((i, j));
            }
        }
    }
    out
}

/// Adds the connected vehicles of `frame` to `seen`.
pub(super) fn note_connected(
    settings: &Settings,
    frame: &TrafficFrame,
    seen: &mut BTreeSet<String>,
) {
    for o in &frame.objects {
        if settings.connected.carries_rig(settings.seeds.sensor, o) {
            seen.insert(o.id.clone());
        }
    }
}

/// Named connected vehicles must all have appeared.
pub(super) fn check_connected_appeared(
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
pub(super) fn sense(
    settings: &Settings,
    scene: &StaticScene,
    frame: &TrafficFrame,
) -> Result<Vec<InstanceSide>, RunError> {
    let mut sides: Vec<InstanceSide> = Vec::new();
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
        let keys = [frame.step, id_hash];
        sides.push(InstanceSide::new(
            ViewSource::Vehicle(o.id.clone()),
            sensed,
            settings.seeds.sensor,
            &keys,
            o.speed_mps,
            None,
        )?);
    }
    sides.sort_by(|a, b| a.id().cmp(b.id()));
    Ok(sides)
}
