//! The simulation loop: SUMO steps, the connected vehicles near the
//! junction sense, and the pairs that are linked and share an object
//! become instances (with `[v2x] mode = "cpm"`, the receptions do), handed
//! out one at a time, per step, or as [`Step`]s that own them.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use super::instance::{Instance, InstanceSide};
use super::{Progress, RunError, SimStats, Warnings};
use crate::bridge::Sumo;
use crate::config::Settings;
use crate::evaluate;
use crate::geometry::{Pose2, Vec2};
use crate::rng::{self, Purpose};
use crate::sensor::gnss;
use crate::sensor::profile::DetectorSettings;
use crate::sensor::{
    self, CameraSettings, ConnectedSelection, LinkSettings, PoseNoiseLabel, PoseNoiseLevel, Sensed,
    SensorSettings,
};
use crate::traffic::{StaticScene, TrafficFrame, TrafficObject};
use crate::v2x::{Receptions, Setup, V2xMode, V2xSettings, ViewSource, true_centres};

/// What sensing reads of the settings: which vehicles carry the rig and
/// within which radius of the junction they sense, what they sense with
/// (`[camera]`, `[sensor]`, `[detector]`, and their own node with
/// `[matching] sender_as_node`), the sensor seed, and how their GNSS
/// reports in `ideal` runs (`[v2x]` at every `[pose_noise]` level).
#[derive(Clone, Copy)]
pub(super) struct Rig<'a> {
    seed: u64,
    traffic_seed: u64,
    appearance: &'a sensor::AppearanceSettings,
    connected: &'a ConnectedSelection,
    radius_m: f64,
    sender_as_node: bool,
    camera: &'a CameraSettings,
    sensor: &'a SensorSettings,
    detector: &'a DetectorSettings,
    pose_noise: &'a [PoseNoiseLevel],
    v2x: &'a V2xSettings,
}

impl<'a> Rig<'a> {
    pub(super) fn of(settings: &'a Settings) -> Self {
        Self {
            seed: settings.seeds.sensor,
            traffic_seed: settings.seeds.traffic,
            appearance: &settings.appearance,
            connected: &settings.connected,
            radius_m: settings.scenario.radius_m,
            sender_as_node: settings.matching.sender_as_node,
            camera: &settings.camera,
            sensor: &settings.sensor,
            detector: &settings.detector,
            pose_noise: &settings.pose_noise,
            v2x: &settings.v2x,
        }
    }

    /// Whether `o` carries the rig.
    fn carries(&self, o: &TrafficObject) -> bool {
        self.connected.carries_rig(self.seed, o)
    }
}

/// Runs the scenario of `settings` from start to end and hands every
/// instance to `on_instance`, in a fixed order (by step, then by vehicle
/// ids).
pub fn simulate(
    settings: &Settings,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    mut on_instance: impl FnMut(&Instance) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    simulate_frames(settings, warnings, progress, |instances| {
        instances.iter().try_for_each(&mut on_instance)
    })
}

/// Runs the scenario of `settings` from start to end and hands the
/// instances of every sampled step to `on_frame` at once (never an empty
/// list), in a fixed order (by step, then by vehicle ids).
pub fn simulate_frames(
    settings: &Settings,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    mut on_frame: impl FnMut(&[Instance]) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    simulate_steps(settings, warnings, progress, |step| {
        on_frame(&step.instances())
    })
}

/// A sampled step with at least one instance, owning what its instances
/// borrow, so that it can be evaluated on another thread.
pub struct Step {
    scene: Arc<StaticScene>,
    frame: TrafficFrame,
    sides: Vec<InstanceSide>,
    /// The instances' sides, as indices into `sides` (ordered by id).
    pairs: Vec<(usize, usize)>,
    /// Each instance's number (a running index within the run).
    numbers: Vec<usize>,
}

impl Step {
    /// A step of `frame` whose instances are `pairs` of `sides` (indices,
    /// ordered by id), the first numbered `first_index`.
    pub(super) fn new(
        scene: Arc<StaticScene>,
        frame: TrafficFrame,
        sides: Vec<InstanceSide>,
        pairs: Vec<(usize, usize)>,
        first_index: usize,
    ) -> Step {
        let numbers = (first_index..first_index + pairs.len()).collect();
        Step::numbered(scene, frame, sides, pairs, numbers)
    }

    /// [`Step::new`] with each instance's number given (a dataset's).
    pub(super) fn numbered(
        scene: Arc<StaticScene>,
        frame: TrafficFrame,
        sides: Vec<InstanceSide>,
        pairs: Vec<(usize, usize)>,
        numbers: Vec<usize>,
    ) -> Step {
        Step {
            scene,
            frame,
            sides,
            pairs,
            numbers,
        }
    }

    /// The step's instances, in order.
    pub fn instances(&self) -> Vec<Instance<'_>> {
        self.pairs
            .iter()
            .zip(&self.numbers)
            .map(|(&(a, b), &index)| Instance {
                index,
                scene: &self.scene,
                frame: &self.frame,
                a: &self.sides[a],
                b: &self.sides[b],
            })
            .collect()
    }
}

/// Runs the scenario of `settings` from start to end and hands every
/// sampled step that has an instance to `on_step`, in order; what the run
/// has to say beside its results goes to `warnings`.
pub fn simulate_steps(
    settings: &Settings,
    warnings: &Warnings,
    mut progress: impl FnMut(Progress),
    mut on_step: impl FnMut(Step) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    if let Some(source) = &settings.dataset {
        return super::replay::dataset_steps(settings, source, warnings, progress, on_step);
    }
    uncalibrated(settings)?;
    let sc = &settings.scenario;
    let rig = Rig::of(settings);
    let cpm = settings.v2x.mode == V2xMode::Cpm;
    let step_length_s = cpm.then_some(settings.v2x.step_length_s);
    let mut sumo = open_sumo(settings, step_length_s)?;
    let scene = Arc::new(sumo.static_scene(&sc.junction)?);
    let setup = cooperation(settings, &settings.pose_noise);
    let mut receptions = cpm.then(Receptions::default);
    let mut stats = SimStats::default();
    let mut seen_connected: BTreeSet<String> = BTreeSet::new();
    let mut seen_types: BTreeSet<String> = BTreeSet::new();
    let mut next_sample_s = f64::NEG_INFINITY;
    let eps = 1e-6;
    while sumo.time_s() + eps < sc.end_s {
        let t0 = Instant::now();
        let frame = sumo.step()?;
        stats.bridge_time += t0.elapsed();
        stats.n_steps += 1;
        stats.objects_read += frame.objects.len() as u64;
        note_connected(&rig, &frame, &mut seen_connected);
        note_types(&frame, &mut seen_types);
        let time_s = frame.time_s;
        let sample = time_s + eps >= next_sample_s;
        let instances = match receptions.as_mut() {
            Some(r) => {
                let vehicles = sense(&rig, &scene, &frame)?;
                Some(receptions_of(setup, r, &frame, &vehicles, sample)?)
            }
            None if sample => {
                let vehicles = sense(&rig, &scene, &frame)?;
                let pairs = instance_pairs(&vehicles, &settings.link);
                Some((vehicles, pairs))
            }
            None => None,
        };
        if let Some((sides, pairs)) = instances
            && !pairs.is_empty()
        {
            let n = pairs.len();
            on_step(Step::new(
                Arc::clone(&scene),
                frame,
                sides,
                pairs,
                stats.n_instances,
            ))?;
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
    warn_unused_types(&settings.detector, &seen_types, warnings);
    Ok(stats)
}

/// What cooperation over time reads of `settings`, with its vehicles'
/// GNSS errors drawn at `levels`.
pub(super) fn cooperation<'a>(settings: &'a Settings, levels: &'a [PoseNoiseLevel]) -> Setup<'a> {
    Setup {
        v: &settings.v2x,
        link: &settings.link,
        sensor_seed: settings.seeds.sensor,
        align_min_matches: settings.fusion.align_min_matches,
        levels,
    }
}

/// A sampled step's sides, and its instances as pairs of indices into them
/// (each pair ordered by id).
type Sides = (Vec<InstanceSide>, Vec<(usize, usize)>);

/// With `[v2x] mode = "cpm"`: one step of the fleet (`vehicles`: what every
/// connected vehicle near the junction sensed), and, when `sample`, the
/// messages that have arrived as instances' sides with their pairs.
fn receptions_of(
    setup: Setup,
    receptions: &mut Receptions,
    frame: &TrafficFrame,
    vehicles: &[InstanceSide],
    sample: bool,
) -> Result<Sides, RunError> {
    let truth = true_centres(frame);
    let ctx = setup.at(frame.step, frame.time_s, &truth);
    let sensings: Vec<_> = vehicles.iter().map(InstanceSide::sensing).collect();
    let (sides, pairs) = receptions.step(&ctx, &sensings, sample);
    let sides = sides
        .into_iter()
        .map(|r| InstanceSide::reception(r, setup.sensor_seed))
        .collect::<Result<_, _>>()?;
    Ok((sides, pairs))
}

/// Adds the types of the road users of `frame` to `seen`.
pub(super) fn note_types(frame: &TrafficFrame, seen: &mut BTreeSet<String>) {
    for o in &frame.objects {
        if !seen.contains(&o.type_id) {
            seen.insert(o.type_id.clone());
        }
    }
}

/// Tells `warnings` which vehicle types `[detector] by_type` and
/// `rig_by_type` name that no road user of the run had (`seen`): those
/// entries changed nothing.
pub(super) fn warn_unused_types(
    detector: &DetectorSettings,
    seen: &BTreeSet<String>,
    warnings: &Warnings,
) {
    let unused = detector.unused_types(seen);
    if unused.is_empty() {
        return;
    }
    let had: Vec<&str> = seen.iter().map(String::as_str).collect();
    warnings.say(&format!(
        "[detector] by_type / rig_by_type name vehicle type(s) {} that no road user of this \
         run had, so they changed nothing (this run's types: {})",
        unused
            .iter()
            .map(|t| format!("'{t}'"))
            .collect::<Vec<_>>()
            .join(", "),
        if had.is_empty() {
            "none".to_owned()
        } else {
            had.join(", ")
        }
    ));
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
pub(super) fn note_connected(rig: &Rig, frame: &TrafficFrame, seen: &mut BTreeSet<String>) {
    for o in &frame.objects {
        if rig.carries(o) {
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
    rig: &Rig,
    scene: &StaticScene,
    frame: &TrafficFrame,
) -> Result<Vec<InstanceSide>, RunError> {
    let mut sides: Vec<InstanceSide> = Vec::new();
    for (k, o) in frame.objects.iter().enumerate() {
        if !rig.carries(o)
            || (o.pose.position_m() - scene.junction_position_m).norm() > rig.radius_m
        {
            continue;
        }
        let id_hash = rng::hash_str(&o.id);
        let mut sensed = sense_one(rig, scene, frame, k);
        if rig.sender_as_node {
            sensed.add_sender(o);
        }
        let keys = [frame.step, id_hash];
        let reported = ideal_gnss(rig, frame, o, id_hash);
        sides.push(InstanceSide::new(
            ViewSource::Vehicle(o.id.clone()),
            sensed,
            rig.seed,
            &keys,
            o.speed_mps,
            reported,
        )?);
    }
    sides.sort_by(|a, b| a.id().cmp(b.id()));
    Ok(sides)
}

/// What connected vehicle `frame.objects[k]` senses at this step, under
/// the configured detector profile (its own stream per step and vehicle).
fn sense_one(rig: &Rig, scene: &StaticScene, frame: &TrafficFrame, k: usize) -> Sensed {
    let id_hash = rng::hash_str(&frame.objects[k].id);
    let mut stream = rng::stream(rig.seed, Purpose::Detections, &[frame.step, id_hash]);
    let (camera, sensor) = (rig.camera, rig.sensor);
    let o = &frame.objects[k];
    let model = rig.detector.model_for(rig.seed, &o.id, &o.type_id);
    let mut sensed = match model {
        None => sensor::observe(frame, scene, k, camera, sensor, &mut stream),
        Some(model) => {
            sensor::profile::observe_profile(frame, scene, k, model, sensor, rig.seed, &mut stream)
        }
    };
    // The boxes' own stream: their errors move no detection.
    let mut boxes = rng::stream(rig.seed, Purpose::BoxMotion, &[frame.step, id_hash]);
    let errors = model.map_or(&sensor.boxes, |m| &m.params.boxes);
    sensor::boxes::add_motion(&mut sensed, frame, k, errors, &mut boxes);
    if let Some(reid) = &rig.appearance.reid {
        let range_m = model.map_or(camera.range_m, |m| m.params.range_m);
        let seeds = (rig.traffic_seed, rig.seed);
        sensor::reid::describe_detections(&mut sensed, frame, k, range_m, seeds, reid);
    }
    sensed
}

/// Refuses to simulate with a re-identification descriptor that was not
/// calibrated (`experiments::calibrate_appearance` comes first): its
/// detections would carry none, silently.
pub(super) fn uncalibrated(settings: &Settings) -> Result<(), RunError> {
    if settings.appearance.uncalibrated() {
        return Err(RunError::Calibration(
            "the re-identification descriptor ([appearance] descriptor = \"reid\") was not \
             calibrated before this run"
                .into(),
        ));
    }
    Ok(())
}

/// SUMO started on the scenario of `settings`, its road users looking as
/// `[sensor] unset_colours` and `[appearance] vehicles` say.
pub(super) fn open_sumo(settings: &Settings, step_length_s: Option<f64>) -> Result<Sumo, RunError> {
    let sc = &settings.scenario;
    let seed = settings.seeds.traffic;
    Ok(Sumo::start(&sc.sumocfg, seed, sc.end_s, step_length_s)?
        .with_unset_colours(settings.sensor.unset_colours, seed)
        .with_catalogue(settings.appearance.catalogue.clone(), seed))
}

/// Runs the scenario of `settings` and gives, for every sampled step and
/// pair of connected vehicles near the junction that see an object in
/// common, both views' detections as the re-identification descriptor
/// sees them ([`sensor::reid::sightings`]): what the descriptor is
/// calibrated on. Returns the pairs and the number of sensings.
pub fn sighting_pairs(
    settings: &Settings,
) -> Result<(Vec<sensor::reid::SightingPair>, u64), RunError> {
    let seeds = (settings.seeds.traffic, settings.seeds.sensor);
    let range_of = |frame: &TrafficFrame, k: usize| {
        let o = &frame.objects[k];
        settings
            .detector
            .model_for(settings.seeds.sensor, &o.id, &o.type_id)
            .map_or(settings.camera.range_m, |m| m.params.range_m)
    };
    let mut pairs = Vec::new();
    let mut step: Option<u64> = None;
    let mut views: Vec<Vec<sensor::reid::Sighting>> = Vec::new();
    let mut flush = |views: &mut Vec<Vec<sensor::reid::Sighting>>| {
        for i in 0..views.len() {
            for j in i + 1..views.len() {
                let shared = views[i]
                    .iter()
                    .any(|s| s.object.is_some() && views[j].iter().any(|t| t.object == s.object));
                if shared {
                    pairs.push(sensor::reid::SightingPair {
                        a: views[i].clone(),
                        b: views[j].clone(),
                    });
                }
            }
        }
        views.clear();
    };
    let n = sense_steps(settings, |frame, sensed| {
        if step != Some(frame.step) {
            flush(&mut views);
            step = Some(frame.step);
        }
        if let Some(k) = frame.find(&sensed.observation.ego_id) {
            let range_m = range_of(frame, k);
            views.push(sensor::reid::sightings(sensed, frame, k, range_m, seeds));
        }
    })?;
    flush(&mut views);
    Ok((pairs, n))
}

/// Runs the scenario of `settings` from start to end and hands what every
/// connected vehicle near the junction senses at every sampled step
/// (`[scenario] sample_every_s`, whether or not it makes an instance) to
/// `on_sensed`, with the frame: the detector report's input. Returns the
/// number of sensings.
pub fn sense_steps(
    settings: &Settings,
    mut on_sensed: impl FnMut(&TrafficFrame, &Sensed),
) -> Result<u64, RunError> {
    let sc = &settings.scenario;
    let rig = Rig::of(settings);
    let mut sumo = open_sumo(settings, None)?;
    let scene = sumo.static_scene(&sc.junction)?;
    let mut next_sample_s = f64::NEG_INFINITY;
    let mut n = 0;
    let eps = 1e-6;
    while sumo.time_s() + eps < sc.end_s {
        let frame = sumo.step()?;
        if frame.time_s + eps < next_sample_s {
            continue;
        }
        next_sample_s = frame.time_s + sc.sample_every_s;
        for (k, o) in frame.objects.iter().enumerate() {
            if rig.carries(o)
                && (o.pose.position_m() - scene.junction_position_m).norm() <= sc.radius_m
            {
                on_sensed(&frame, &sense_one(&rig, &scene, &frame, k));
                n += 1;
            }
        }
    }
    sumo.close()?;
    Ok(n)
}

/// With `[v2x] mode = "ideal"` and a GNSS that drifts or whose heading
/// error grows at low speed, the pose `o` reports at every level (drawn
/// here, carried by its side); `None` with the white model, whose poses
/// the side draws from its own stream when asked (the shipped results).
fn ideal_gnss(
    rig: &Rig,
    frame: &TrafficFrame,
    o: &TrafficObject,
    id_hash: u64,
) -> Option<Vec<(PoseNoiseLabel, Pose2)>> {
    let v = rig.v2x;
    if v.mode != V2xMode::Ideal {
        return None;
    }
    let at = gnss::VehicleAt {
        seed: rig.seed,
        step: frame.step,
        time_s: frame.time_s,
        vehicle_hash: id_hash,
        speed_mps: o.speed_mps,
    };
    gnss::ideal_poses(
        at,
        rig.pose_noise,
        v.gnss_correlation_s,
        v.gnss_heading_speed_sigma_mps,
        &o.pose,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;
    use crate::pipeline::tests::{self as fixtures, scene, settings, vehicle_side};

    fn car(id: &str, x: f64, y: f64) -> crate::traffic::TrafficObject {
        fixtures::car(id, Pose2::new(Vec2::new(x, y), 0.0))
    }

    /// Two sides are an instance when both detect a common object and
    /// their link allows it; a pair is listed once, lower index first.
    #[test]
    fn linked_sides_that_share_an_object_are_instances() {
        let at = |x: f64| Pose2::new(Vec2::new(x, 0.0), 0.0);
        let sides = [
            vehicle_side("cv0", at(0.0), &[("a", Vec2::new(10.0, 0.0))], 1),
            vehicle_side("cv1", at(50.0), &[("a", Vec2::new(10.0, 0.0))], 1),
            vehicle_side("cv2", at(60.0), &[("b", Vec2::new(70.0, 0.0))], 1),
            vehicle_side("cv3", at(65.0), &[("b", Vec2::new(70.0, 0.0))], 1),
        ];
        let all = LinkSettings::default();
        assert_eq!(instance_pairs(&sides, &all), [(0, 1), (2, 3)]);
        let near = LinkSettings {
            comm_range_m: Some(20.0),
            max_peers: None,
        };
        assert_eq!(instance_pairs(&sides, &near), [(2, 3)]);
    }

    /// Named connected vehicles that never appeared are listed in the
    /// error; with a penetration nobody is named.
    #[test]
    fn connected_vehicles_named_but_never_seen_are_an_error() {
        let s = settings();
        let mut seen = BTreeSet::new();
        let frame = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![car("cv0", 0.0, 0.0), car("other", 5.0, 0.0)],
        };
        note_connected(&Rig::of(&s), &frame, &mut seen);
        assert_eq!(seen.iter().collect::<Vec<_>>(), ["cv0"]);
        let ids = ConnectedSelection::Ids(vec!["cv0".into(), "cv1".into()]);
        match check_connected_appeared(&ids, &seen) {
            Err(RunError::MissingConnectedVehicles(m)) => assert_eq!(m, ["cv1"]),
            other => panic!("{other:?}"),
        }
        seen.insert("cv1".into());
        assert!(check_connected_appeared(&ids, &seen).is_ok());
        let share = ConnectedSelection::Penetration(0.5);
        assert!(check_connected_appeared(&share, &BTreeSet::new()).is_ok());
    }

    /// Only connected vehicles within the radius of the junction sense;
    /// their sides are sorted by id and carry their own node.
    #[test]
    fn the_connected_vehicles_near_the_junction_sense_in_id_order() {
        let s = settings();
        let scene = scene();
        let far = s.scenario.radius_m + 10.0;
        let frame = TrafficFrame {
            step: 4,
            time_s: 0.4,
            objects: vec![
                car("cv1", 5.0, 0.0),
                car("x", 15.0, 0.0),
                car("cv0", -20.0, 3.5),
                car("y", far, 0.0),
            ],
        };
        let sides = sense(&Rig::of(&s), &scene, &frame).unwrap();
        let ids: Vec<&str> = sides.iter().map(InstanceSide::id).collect();
        assert_eq!(ids, ["cv0", "cv1"]);
        assert!(sides.iter().all(|e| e.sensed.own_node().is_some()));
        let mut none = s.clone();
        none.scenario.radius_m = 1.0;
        assert!(sense(&Rig::of(&none), &scene, &frame).unwrap().is_empty());
    }
}
