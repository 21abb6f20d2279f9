//! One headless run: SUMO steps -> sensing -> graphs -> instances, each
//! handed out at every pose-noise level for [`evaluate`] to match, count
//! and fuse. The stages are called here in order with their own settings.
//! The only file this module reads is a deep method's weights, through
//! `io`; it writes nothing (the caller writes the results).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::bridge::{BridgeError, Sumo};
use crate::config::Settings;
use crate::evaluate::{self, PairAtLevel, Runner, Side};
use crate::geometry::{Pose2, Vec2};
use crate::graph::{GraphError, SceneGraph};
use crate::io::{self, OutputError, WeightsError};
use crate::matching::deep::decision::Decision;
use crate::matching::{
    self, BuildError, DecisionChoice, DeepChoice, LambdaChoice, MatchView, Method, MethodKind,
};
use crate::report::{ObjectRow, RowKey, RunResults};
use crate::rng::{self, Purpose};
use crate::sensor::{
    self, ConnectedSelection, LinkSettings, PoseNoiseLabel, PoseNoiseLevel, Sensed,
};
use crate::traffic::{StaticScene, TrafficFrame};
use crate::v2x::V2xMode;

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
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{0}")]
    Worker(String),
    /// Correspondences made elsewhere that do not fit the run.
    #[error("{0}")]
    Matches(String),
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

/// A connected vehicle near the junction at one step, with what it sees;
/// or, with `[v2x] mode = "cpm"`, one side of a reception: a receiver's
/// reported tracks, or a message it received.
pub struct Ego {
    pub sensed: Sensed,
    pub graph: SceneGraph,
    id_hash: u64,
    /// The vehicle's speed (m/s), forward.
    speed_mps: f64,
    /// The GNSS-reported pose at every level, when it is carried over time
    /// (`[v2x] mode = "cpm"`) instead of drawn afresh at each step.
    reported: Option<Vec<(PoseNoiseLabel, Pose2)>>,
}

impl Ego {
    /// A side from what it holds: its nodes listed in the order of the
    /// `Purpose::NodeOrder` stream `order_keys` (no order may carry
    /// labels), then its Delaunay graph.
    fn new(
        mut sensed: Sensed,
        sensor_seed: u64,
        order_keys: &[u64],
        speed_mps: f64,
        reported: Option<Vec<(PoseNoiseLabel, Pose2)>>,
    ) -> Result<Ego, RunError> {
        sensed.shuffle(&mut rng::stream(
            sensor_seed,
            Purpose::NodeOrder,
            order_keys,
        ));
        let positions: Vec<Vec2> = sensed
            .observation
            .detections
            .iter()
            .map(|d| d.position_m)
            .collect();
        let graph = SceneGraph::delaunay(&positions)?;
        let id_hash = rng::hash_str(&sensed.observation.ego_id);
        Ok(Ego {
            sensed,
            graph,
            id_hash,
            speed_mps,
            reported,
        })
    }

    /// The pose this vehicle's GPS reports at `step` at a noise level (its
    /// own seeded stream per step, vehicle and level), or the one it
    /// carries at that level.
    pub fn reported_pose(&self, sensor_seed: u64, step: u64, level: &PoseNoiseLevel) -> Pose2 {
        if let Some(carried) = &self.reported {
            return carried
                .iter()
                .find(|(l, _)| *l == level.label)
                .map(|(_, p)| *p)
                .expect("a side carries a pose at every level of its run");
        }
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
            instance: self.index,
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
    egos: Vec<Ego>,
    /// The instances' vehicles, as indices into `egos` (ordered by id).
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
                a: &self.egos[a],
                b: &self.egos[b],
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
        let sides = match receptions.as_mut() {
            Some(r) => {
                let egos = sense(settings, &scene, &frame)?;
                Some(r.step(settings, &frame, &egos, sample)?)
            }
            None if sample => {
                let egos = sense(settings, &scene, &frame)?;
                let pairs = instance_pairs(&egos, &settings.link);
                Some((egos, pairs))
            }
            None => None,
        };
        if let Some((egos, pairs)) = sides
            && !pairs.is_empty()
        {
            let n = pairs.len();
            on_step(Step {
                scene: Arc::clone(&scene),
                frame,
                egos,
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

/// The instances of one step: every pair of `egos` (sorted by id) whose
/// cameras detect a common object and that `link` lets talk to each other.
fn instance_pairs(egos: &[Ego], link: &LinkSettings) -> Vec<(usize, usize)> {
    let positions: Vec<Vec2> = egos
        .iter()
        .map(|e| e.sensed.truth.ego_pose.position_m())
        .collect();
    let links = link.links(&positions);
    let mut out = Vec::new();
    for (i, a) in egos.iter().enumerate() {
        for (j, b) in egos.iter().enumerate().skip(i + 1) {
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
fn note_connected(settings: &Settings, frame: &TrafficFrame, seen: &mut BTreeSet<String>) {
    for o in &frame.objects {
        if settings.connected.carries_rig(settings.seeds.sensor, o) {
            seen.insert(o.id.clone());
        }
    }
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
        let keys = [frame.step, id_hash];
        egos.push(Ego::new(
            sensed,
            settings.seeds.sensor,
            &keys,
            o.speed_mps,
            None,
        )?);
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
        .filter(|m| matches!(m.kind(), MethodKind::Deep(_)))
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
    let (weights, choice) = if let MethodKind::Deep(_) = method.kind() {
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
/// ([`evaluate::evaluate_frame`], with `[matching] multi_vehicle`) on
/// `threads` threads. The summary is accumulated as the frames come;
/// every per-object row goes to `on_objects` in a fixed order (by step,
/// pose-noise level, method, instance), whatever the number of threads, and
/// is not kept.
pub fn run(
    settings: &Settings,
    threads: usize,
    progress: impl FnMut(Progress),
    mut on_objects: impl FnMut(&[ObjectRow]) -> Result<(), OutputError>,
) -> Result<RunResults, RunError> {
    let started = Instant::now();
    let runners = runners(settings, &settings.matching.methods)?;
    let mut results = RunResults::default();
    // Every row is there from the start: a run without any instance has
    // them too (`n_instances` 0, no metric), so it is a complete run.
    for &method in &settings.matching.methods {
        for level in &settings.pose_noise {
            for &fusion in &settings.fusion.variants {
                let key = RowKey {
                    method,
                    pose_noise: level.label,
                    fusion,
                };
                results.summary.rows.entry(key).or_default();
            }
        }
    }
    let mut rows = Vec::new();
    let stats = evaluate_frames(
        settings,
        &runners,
        threads,
        progress,
        |instances, _, level, f| {
            rows.clear();
            record_frame(&mut results, &mut rows, instances, level, f);
            Ok(on_objects(&rows)?)
        },
    )?;
    results.n_instances = stats.n_instances;
    results.n_steps = stats.n_steps;
    results.sim_end_s = stats.sim_end_s;
    results.bridge_time = stats.bridge_time;
    results.objects_read = stats.objects_read;
    results.wall_time = started.elapsed();
    Ok(results)
}

/// What [`evaluate_frames`] hands on: a step's instances, their pairs at a
/// level, the level, and one runner's evaluation of them.
pub type OnEval<'a> = dyn FnMut(&[Instance], &[PairAtLevel], PoseNoiseLabel, evaluate::FrameEval) -> Result<(), RunError>
    + 'a;

/// Runs the scenario and hands every frame's evaluation to `on_eval`: for
/// each sampled step, each pose-noise level and each runner in order, the
/// step's instances, their pairs at that level, the level, and what
/// [`evaluate::evaluate_frame`] made of them (with `[matching]
/// multi_vehicle`). With `threads` > 1, SUMO and sensing go on in this
/// thread while `threads` others evaluate the steps already sensed (a
/// runner's levels of one step are one task); `on_eval` still sees
/// everything in the same order, so the results do not depend on the
/// number of threads.
pub fn evaluate_frames(
    settings: &Settings,
    runners: &[Runner],
    threads: usize,
    progress: impl FnMut(Progress),
    mut on_eval: impl FnMut(
        &[Instance],
        &[PairAtLevel],
        PoseNoiseLabel,
        evaluate::FrameEval,
    ) -> Result<(), RunError>,
) -> Result<SimStats, RunError> {
    if threads <= 1 {
        return simulate_steps(settings, progress, |step| {
            let evals = runners
                .iter()
                .map(|r| evaluate_step(settings, &step, r))
                .collect();
            hand_on(settings, &step, evals, &mut on_eval)
        });
    }
    parallel::evaluate_frames(settings, runners, threads, progress, &mut on_eval)
}

/// One runner's evaluation of a step at every pose-noise level, in order.
fn evaluate_step(settings: &Settings, step: &Step, runner: &Runner) -> Vec<evaluate::FrameEval> {
    let instances = step.instances();
    settings
        .pose_noise
        .iter()
        .map(|level| {
            let pairs = pairs_at(settings, &instances, level);
            evaluate::evaluate_frame(
                &pairs,
                runner,
                &settings.fusion,
                settings.matching.multi_vehicle,
            )
        })
        .collect()
}

fn pairs_at<'a>(
    settings: &Settings,
    instances: &[Instance<'a>],
    level: &PoseNoiseLevel,
) -> Vec<PairAtLevel<'a>> {
    instances
        .iter()
        .map(|i| i.at_level(settings.seeds.sensor, level))
        .collect()
}

/// Hands a step's evaluations (`evals[runner][level]`) to `on_eval`,
/// level by level, runner by runner.
fn hand_on(
    settings: &Settings,
    step: &Step,
    evals: Vec<Vec<evaluate::FrameEval>>,
    on_eval: &mut OnEval,
) -> Result<(), RunError> {
    let instances = step.instances();
    let mut by_runner: Vec<std::vec::IntoIter<evaluate::FrameEval>> =
        evals.into_iter().map(Vec::into_iter).collect();
    for level in &settings.pose_noise {
        let pairs = pairs_at(settings, &instances, level);
        for r in &mut by_runner {
            let f = r.next().expect("one evaluation per level");
            on_eval(&instances, &pairs, level.label, f)?;
        }
    }
    Ok(())
}

mod over_time;
mod receptions;
pub use over_time::track;

/// The threaded form of [`evaluate_frames`].
mod parallel {
    use std::collections::BTreeMap;
    use std::panic::{AssertUnwindSafe, catch_unwind};
    use std::sync::mpsc::{self, Receiver, Sender};
    use std::sync::{Arc, Mutex};

    use super::{OnEval, Progress, RunError, SimStats, Step, evaluate_step, hand_on};
    use crate::config::Settings;
    use crate::evaluate::{FrameEval, Runner};

    /// One task: a runner on a step.
    struct Task {
        seq: usize,
        step: Arc<Step>,
        runner: usize,
    }

    /// A finished task (`None`: it panicked).
    struct Done {
        seq: usize,
        runner: usize,
        evals: Option<Vec<FrameEval>>,
    }

    /// A step handed out, with the evaluations that are in (one slot per
    /// runner).
    struct Pending {
        step: Arc<Step>,
        evals: Vec<Option<Vec<FrameEval>>>,
    }

    /// Steps handed out and not yet handed on, by sequence number.
    struct InFlight {
        runners: usize,
        next: usize,
        steps: BTreeMap<usize, Pending>,
    }

    impl InFlight {
        fn put(&mut self, d: Done) -> Result<(), RunError> {
            let evals = d.evals.ok_or_else(|| {
                RunError::Worker("an evaluation thread panicked (a bug: please report it)".into())
            })?;
            let pending = self
                .steps
                .get_mut(&d.seq)
                .expect("a task of a step in flight");
            pending.evals[d.runner] = Some(evals);
            Ok(())
        }

        /// Hands on every complete step at the front, in order.
        fn hand_on_ready(
            &mut self,
            settings: &Settings,
            on_eval: &mut OnEval,
        ) -> Result<(), RunError> {
            while let Some(entry) = self.steps.first_entry() {
                if *entry.key() != self.next || entry.get().evals.iter().any(Option::is_none) {
                    break;
                }
                let Pending { step, evals } = entry.remove();
                let evals = evals.into_iter().map(Option::unwrap).collect();
                hand_on(settings, &step, evals, on_eval)?;
                self.next += 1;
            }
            Ok(())
        }
    }

    fn worker(
        settings: &Settings,
        runners: &[Runner],
        tasks: &Mutex<Receiver<Task>>,
        done: Sender<Done>,
    ) {
        loop {
            let task = match tasks.lock() {
                Ok(rx) => rx.recv(),
                Err(_) => return,
            };
            let Ok(t) = task else { return };
            let evals = catch_unwind(AssertUnwindSafe(|| {
                evaluate_step(settings, &t.step, &runners[t.runner])
            }))
            .ok();
            let d = Done {
                seq: t.seq,
                runner: t.runner,
                evals,
            };
            if done.send(d).is_err() {
                return;
            }
        }
    }

    pub(super) fn evaluate_frames(
        settings: &Settings,
        runners: &[Runner],
        threads: usize,
        progress: impl FnMut(Progress),
        on_eval: &mut OnEval,
    ) -> Result<SimStats, RunError> {
        // Steps sensed ahead of the one handed on next: enough to keep every
        // thread busy, few enough to bound the memory.
        let max_in_flight = 2 * threads;
        let (task_tx, task_rx) = mpsc::channel::<Task>();
        let (done_tx, done_rx) = mpsc::channel::<Done>();
        let task_rx = Mutex::new(task_rx);
        let mut flight = InFlight {
            runners: runners.len(),
            next: 0,
            steps: BTreeMap::new(),
        };
        std::thread::scope(|scope| {
            for k in 0..threads {
                let done = done_tx.clone();
                let tasks = &task_rx;
                let started = std::thread::Builder::new()
                    .name(format!("coid-eval-{k}"))
                    .spawn_scoped(scope, move || worker(settings, runners, tasks, done));
                if let Err(e) = started {
                    // The threads already started end once the queue closes.
                    drop(task_tx);
                    return Err(RunError::Worker(format!(
                        "cannot start evaluation thread {} of {threads}: {e} (use fewer --threads)",
                        k + 1
                    )));
                }
            }
            drop(done_tx);
            let mut seq = 0;
            let result = super::simulate_steps(settings, progress, |step| {
                let step = Arc::new(step);
                let evals = (0..flight.runners).map(|_| None).collect();
                let pending = Pending {
                    step: Arc::clone(&step),
                    evals,
                };
                flight.steps.insert(seq, pending);
                for runner in 0..runners.len() {
                    let t = Task {
                        seq,
                        step: Arc::clone(&step),
                        runner,
                    };
                    task_tx.send(t).map_err(|_| {
                        RunError::Worker("the evaluation threads ended early".into())
                    })?;
                }
                seq += 1;
                while let Ok(d) = done_rx.try_recv() {
                    flight.put(d)?;
                }
                flight.hand_on_ready(settings, on_eval)?;
                while flight.steps.len() >= max_in_flight {
                    wait_one(&done_rx, &mut flight)?;
                    flight.hand_on_ready(settings, on_eval)?;
                }
                Ok(())
            });
            // No more tasks: the threads end once the queue is empty.
            drop(task_tx);
            let stats = result?;
            while !flight.steps.is_empty() {
                wait_one(&done_rx, &mut flight)?;
                flight.hand_on_ready(settings, on_eval)?;
            }
            Ok(stats)
        })
    }

    fn wait_one(rx: &Receiver<Done>, flight: &mut InFlight) -> Result<(), RunError> {
        let d = rx
            .recv()
            .map_err(|_| RunError::Worker("the evaluation threads ended early".into()))?;
        flight.put(d)
    }
}

/// Adds one method's evaluation of a frame at one level to `results`, and
/// its per-object rows to `rows`.
fn record_frame(
    results: &mut RunResults,
    rows: &mut Vec<ObjectRow>,
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
            rows.extend(est.into_iter().map(|estimate| ObjectRow {
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
