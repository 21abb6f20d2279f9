//! A re-identification descriptor (`[appearance] descriptor = "reid"`):
//! what a re-identification network's features would say about each
//! detection, as a vector of configurable width whose cross-view quality
//! is calibrated to a target.
//!
//! A detection's descriptor is its road user's look plus noise. The look
//! is a sum of fixed directions of the descriptor space (drawn once from
//! named streams, the same in every run): its class, its model (from the
//! catalogue, else its SUMO type) as seen from the front, the side or the
//! rear (blended by the angle at which the camera sees it), its paint (a
//! fixed projection of the RGB colour, so that white and silver are
//! close) and the vehicle's own features (per id and traffic seed: the
//! number plate, dirt, a roof box). The noise is Gaussian with standard
//! deviation `sigma exp(d / range + 1 - visible)`, so it grows with
//! distance and occlusion. Each view adds a bias of its own (a direction
//! and a strength drawn per camera and step, `bias` at most: the
//! lighting and exposure every detection of one image shares), which
//! moves all of a view's similarities together. Calibration
//! ([`calibrate`]) chooses `sigma` and `bias` on the validation runs so
//! that the cross-view rank-1 rate and the same/different AUROC
//! ([`figures`]) meet their targets.

use crate::geometry::Vec2;
use crate::rng::{self, Purpose};
use crate::traffic::{ObjectClass, TrafficFrame};

use super::{DescriptorLaw, Sensed};

/// `[appearance] descriptor = "reid"`: the descriptor's width and the
/// figures it is calibrated to, and the calibration once made.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidSettings {
    pub width: usize,
    pub target: ReidTarget,
    /// Made on the validation runs ([`calibrate`]) before any run uses the
    /// descriptor.
    pub calibration: Option<ReidCalibration>,
}

/// The cross-view figures a descriptor is calibrated to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidTarget {
    pub rank1: f64,
    /// `None`: only the rank-1 rate is calibrated, the views carry no
    /// bias.
    pub auroc: Option<f64>,
}

/// The noise of the descriptor: standard deviation `sigma exp(spoil)`
/// per unit of the look's scale (`spoil = d / range + 1 - visible`), and
/// the largest strength of a view's bias.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidNoise {
    pub sigma: f64,
    pub bias: f64,
}

/// A calibration: the noise, what the cosine says (fitted on the same
/// validation pairs; `None` when it tells nothing apart) and the figures
/// measured at the noise.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidCalibration {
    pub noise: ReidNoise,
    pub law: Option<DescriptorLaw>,
    pub figures: ReidFigures,
}

/// How well descriptors re-identify objects across two views.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReidFigures {
    /// The share of objects seen in both views whose partner is the most
    /// similar (by cosine) of the other view's detections.
    pub rank1: f64,
    /// The probability that a same-object pair is more similar than a
    /// pair of different objects (or a false positive).
    pub auroc: f64,
    /// Objects seen in both views, counted from each side.
    pub queries: usize,
    /// The mean number of candidates a query is ranked among.
    pub candidates: f64,
    /// Mean cosine of same-object pairs and of the others.
    pub same_cos: f64,
    pub different_cos: f64,
}

/// The largest view bias calibration tries.
const MAX_BIAS: f64 = 30.0;

/// Weights of the look's parts [assume: chosen so that a model and a
/// paint together say about as much as the vehicle's own features; the
/// noise, calibrated, decides how much of it survives].
const CLASS_WEIGHT: f64 = 0.5;
const MODEL_WEIGHT: f64 = 1.0;
/// How much the model's look differs between front, side and rear.
const VIEW_WEIGHT: f64 = 0.6;
const PAINT_WEIGHT: f64 = 0.8;
const INDIVIDUAL_WEIGHT: f64 = 1.5;

/// The seed of the descriptor space's fixed directions (not a run's: the
/// same "network" describes every run).
const SPACE_SEED: u64 = 0x5EED_0052;

/// One detection as the descriptor sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Sighting {
    /// The detected object (its id's hash; `None` for a false positive):
    /// labels for calibration only.
    pub object: Option<u64>,
    pub class: ObjectClass,
    /// The model's name in the descriptor space (catalogue index or SUMO
    /// type).
    pub model_key: u64,
    /// The paint, RGB in [0, 1].
    pub colour_rgb: [f64; 3],
    /// The vehicle's own features (per id and traffic seed).
    pub individual_key: u64,
    /// Where the camera is as the object sees it: 0 ahead (its front is
    /// seen), pi behind (its rear), +-pi/2 beside it.
    pub view_rad: f64,
    /// `d / range + 1 - visible fraction`: what makes the noise grow.
    pub spoil: f64,
    /// The name of its noise stream.
    pub noise_key: u64,
    /// The view it belongs to (camera and step): the name of the view's
    /// bias.
    pub view_key: u64,
}

/// A fixed direction of the descriptor space: N(0, 1/width) per entry.
fn direction(parts: &[u64], width: usize) -> Vec<f64> {
    let mut s = rng::stream(SPACE_SEED, Purpose::ReidLook, parts);
    normals(&mut s, width)
}

fn normals(s: &mut impl rand::Rng, width: usize) -> Vec<f64> {
    let scale = 1.0 / (width as f64).sqrt();
    (0..width)
        .map(|_| scale * s.sample::<f64, _>(rand_distr::StandardNormal))
        .collect()
}

fn add(v: &mut [f64], w: f64, d: &[f64]) {
    for (x, y) in v.iter_mut().zip(d) {
        *x += w * y;
    }
}

/// The look of a sighting, before noise.
pub fn look(s: &Sighting, width: usize) -> Vec<f64> {
    let mut v = vec![0.0; width];
    let class = ObjectClass::ALL
        .iter()
        .position(|c| *c == s.class)
        .unwrap_or(0) as u64;
    add(&mut v, CLASS_WEIGHT, &direction(&[1, class], width));
    add(&mut v, MODEL_WEIGHT, &direction(&[2, s.model_key], width));
    let (c, sn) = (s.view_rad.cos(), s.view_rad.sin());
    let views = [
        (c.max(0.0).powi(2), 3),
        (sn * sn, 4),
        ((-c).max(0.0).powi(2), 5),
    ];
    for (w, code) in views {
        if w > 0.0 {
            add(
                &mut v,
                MODEL_WEIGHT * VIEW_WEIGHT * w,
                &direction(&[code, s.model_key], width),
            );
        }
    }
    let paint_scale = PAINT_WEIGHT / 3f64.sqrt();
    for (k, c) in s.colour_rgb.iter().enumerate() {
        add(
            &mut v,
            paint_scale * (2.0 * c - 1.0),
            &direction(&[7, k as u64], width),
        );
    }
    add(
        &mut v,
        INDIVIDUAL_WEIGHT,
        &direction(&[6, s.individual_key], width),
    );
    v
}

/// The sighting's noise direction (unscaled).
fn noise(s: &Sighting, width: usize) -> Vec<f64> {
    let mut stream = rng::stream(SPACE_SEED, Purpose::ReidNoise, &[s.noise_key]);
    normals(&mut stream, width)
}

fn noise_scale(s: &Sighting, n: ReidNoise) -> f64 {
    n.sigma * s.spoil.exp()
}

/// The direction of a view's bias (unscaled).
fn view_bias(s: &Sighting, width: usize) -> Vec<f64> {
    let mut stream = rng::stream(SPACE_SEED, Purpose::ReidNoise, &[1, s.view_key]);
    normals(&mut stream, width)
}

/// The strength of a view's bias: `bias` times a share drawn per view.
fn bias_scale(s: &Sighting, n: ReidNoise) -> f64 {
    n.bias * rng::unit(SPACE_SEED, Purpose::ReidNoise, &[2, s.view_key])
}

/// The descriptor of a sighting at `noise`: its look plus the noise and
/// its view's bias, scaled to unit length.
pub fn describe(s: &Sighting, width: usize, n: ReidNoise) -> Vec<f32> {
    let mut v = look(s, width);
    add(&mut v, noise_scale(s, n), &noise(s, width));
    add(&mut v, bias_scale(s, n), &view_bias(s, width));
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-12);
    v.iter().map(|x| (x / norm) as f32).collect()
}

/// One sighting per detection of `sensed` (in its order), from the truth
/// behind it: `frame` is the step it was sensed at, `ego` the sensing
/// vehicle's index in it, `range_m` its camera's range.
pub fn sightings(
    sensed: &Sensed,
    frame: &TrafficFrame,
    ego: usize,
    range_m: f64,
    seeds: (u64, u64),
) -> Vec<Sighting> {
    let (traffic_seed, sensor_seed) = seeds;
    let ego_obj = &frame.objects[ego];
    let ego_hash = rng::hash_str(&ego_obj.id);
    let ego_at = ego_obj.pose.position_m();
    let obs = &sensed.observation.detections;
    obs.iter()
        .zip(&sensed.truth.detections)
        .map(|(det, truth)| {
            let object = truth
                .object_id
                .as_deref()
                .and_then(|id| frame.find(id))
                .map(|k| &frame.objects[k]);
            match object {
                Some(o) => {
                    let id_hash = rng::hash_str(&o.id);
                    let model_key = match o.model {
                        Some(m) => rng::key(&[1, u64::from(m)]),
                        None => rng::key(&[2, rng::hash_str(&o.type_id)]),
                    };
                    let seen_from = o.pose.to_body(&ego_at);
                    let d = (o.pose.position_m() - ego_at).norm();
                    Sighting {
                        object: Some(id_hash),
                        class: o.class,
                        model_key,
                        colour_rgb: o.colour_rgb.map(|c| f64::from(c) / 255.0),
                        individual_key: rng::key(&[traffic_seed, id_hash]),
                        view_rad: seen_from.y.atan2(seen_from.x),
                        spoil: d / range_m + (1.0 - truth.visible_fraction),
                        noise_key: rng::key(&[sensor_seed, frame.step, ego_hash, id_hash]),
                        view_key: rng::key(&[sensor_seed, frame.step, ego_hash]),
                    }
                }
                None => clutter(det, frame.step, ego_hash, range_m, sensor_seed),
            }
        })
        .collect()
}

/// A false positive's sighting: a look of no vehicle (its own model and
/// features, its observed colour), seen from an angle of its own.
fn clutter(
    det: &super::Detection,
    step: u64,
    ego_hash: u64,
    range_m: f64,
    sensor_seed: u64,
) -> Sighting {
    let at: Vec2 = det.position_m;
    let key = rng::key(&[sensor_seed, step, ego_hash, at.x.to_bits(), at.y.to_bits()]);
    Sighting {
        object: None,
        class: det.appearance.class,
        model_key: rng::key(&[3, key]),
        colour_rgb: det.appearance.colour_rgb,
        individual_key: rng::key(&[4, key]),
        view_rad: rng::unit(SPACE_SEED, Purpose::ReidLook, &[8, key]) * std::f64::consts::TAU,
        spoil: at.norm() / range_m + 1.0,
        noise_key: key,
        view_key: rng::key(&[sensor_seed, step, ego_hash]),
    }
}

/// Two views' detections and the cosine of every pair (row-major, `a` by
/// `b`), with the objects behind them.
#[derive(Clone, Debug, Default)]
pub struct ScoredScene {
    pub a: Vec<Option<u64>>,
    pub b: Vec<Option<u64>>,
    pub cos: Vec<f64>,
}

impl ScoredScene {
    /// A scene from two views' descriptors.
    pub fn of(a: &[(Option<u64>, &[f32])], b: &[(Option<u64>, &[f32])]) -> Self {
        let cos = a
            .iter()
            .flat_map(|x| b.iter().map(|y| super::cosine(x.1, y.1)))
            .collect();
        Self {
            a: a.iter().map(|x| x.0).collect(),
            b: b.iter().map(|x| x.0).collect(),
            cos,
        }
    }

    fn same(&self, i: usize, j: usize) -> bool {
        self.a[i].is_some() && self.a[i] == self.b[j]
    }
}

/// The rank-1 rate over `scenes` (from both sides): the share of objects
/// seen in both views whose partner is strictly the most similar of the
/// other view's detections; with the number of queries and the mean
/// number of candidates.
fn rank1(scenes: &[ScoredScene]) -> (f64, usize, f64) {
    let (mut hits, mut queries, mut candidates) = (0usize, 0usize, 0usize);
    for s in scenes {
        let (na, nb) = (s.a.len(), s.b.len());
        for i in 0..na {
            let Some(j) = (0..nb).find(|&j| s.same(i, j)) else {
                continue;
            };
            let c = s.cos[i * nb + j];
            queries += 1;
            candidates += nb;
            hits += usize::from((0..nb).all(|k| k == j || s.cos[i * nb + k] < c));
        }
        for j in 0..nb {
            let Some(i) = (0..na).find(|&i| s.same(i, j)) else {
                continue;
            };
            let c = s.cos[i * nb + j];
            queries += 1;
            candidates += na;
            hits += usize::from((0..na).all(|k| k == i || s.cos[k * nb + j] < c));
        }
    }
    if queries == 0 {
        return (0.0, 0, 0.0);
    }
    (
        hits as f64 / queries as f64,
        queries,
        candidates as f64 / queries as f64,
    )
}

/// Every pair's cosine with whether it shows one object.
pub fn labelled_pairs(scenes: &[ScoredScene]) -> Vec<(f64, bool)> {
    let mut out = Vec::new();
    for s in scenes {
        let nb = s.b.len();
        for i in 0..s.a.len() {
            for j in 0..nb {
                out.push((s.cos[i * nb + j], s.same(i, j)));
            }
        }
    }
    out
}

/// The Mann-Whitney AUROC of same-object pairs against the others (ties
/// count a half); 0.5 without pairs of both kinds.
fn auroc(pairs: &mut [(f64, bool)]) -> f64 {
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    let positives = pairs.iter().filter(|p| p.1).count();
    let negatives = pairs.len() - positives;
    if positives == 0 || negatives == 0 {
        return 0.5;
    }
    let mut rank_sum = 0.0;
    let mut k = 0;
    while k < pairs.len() {
        let mut end = k;
        while end < pairs.len() && pairs[end].0 == pairs[k].0 {
            end += 1;
        }
        let mid_rank = (k + 1 + end) as f64 / 2.0;
        rank_sum += mid_rank * pairs[k..end].iter().filter(|p| p.1).count() as f64;
        k = end;
    }
    let p = positives as f64;
    (rank_sum - p * (p + 1.0) / 2.0) / (p * negatives as f64)
}

/// How well the descriptors of `scenes` re-identify objects.
pub fn figures(scenes: &[ScoredScene]) -> ReidFigures {
    let (rank1, queries, candidates) = rank1(scenes);
    let mut pairs = labelled_pairs(scenes);
    let mean = |same: bool| {
        let v: Vec<f64> = pairs.iter().filter(|p| p.1 == same).map(|p| p.0).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let (same_cos, different_cos) = (mean(true), mean(false));
    ReidFigures {
        rank1,
        auroc: auroc(&mut pairs),
        queries,
        candidates,
        same_cos,
        different_cos,
    }
}

/// One view's detections with a descriptor: the object behind each, and
/// its descriptor.
type DescribedView = Vec<(Option<u64>, std::sync::Arc<[f32]>)>;

/// The descriptors the sensor gave, gathered view by view and step by
/// step into scored scenes (every pair of views of one step that share an
/// object): the figures of the descriptors themselves, as `coid detector`
/// measures them.
#[derive(Default)]
pub struct DescribedViews {
    step: Option<u64>,
    views: Vec<DescribedView>,
    scenes: Vec<ScoredScene>,
}

impl DescribedViews {
    /// Adds one vehicle's sensing at `step` (its detections with a
    /// descriptor).
    pub fn add(&mut self, step: u64, sensed: &Sensed) {
        if self.step != Some(step) {
            self.flush();
            self.step = Some(step);
        }
        let view = sensed
            .observation
            .detections
            .iter()
            .zip(&sensed.truth.detections)
            .filter_map(|(d, t)| {
                let values = d.appearance.descriptor.as_ref()?.values.clone();
                Some((t.object_id.as_deref().map(rng::hash_str), values))
            })
            .collect();
        self.views.push(view);
    }

    fn flush(&mut self) {
        let views = std::mem::take(&mut self.views);
        for (i, a) in views.iter().enumerate() {
            for b in &views[i + 1..] {
                let shared = a
                    .iter()
                    .any(|x| x.0.is_some() && b.iter().any(|y| y.0 == x.0));
                if shared {
                    let side = |v: &[(Option<u64>, std::sync::Arc<[f32]>)]| -> Vec<(Option<u64>, Vec<f32>)> {
                        v.iter().map(|(o, d)| (*o, d.to_vec())).collect()
                    };
                    let (sa, sb) = (side(a), side(b));
                    let ra: Vec<(Option<u64>, &[f32])> =
                        sa.iter().map(|(o, d)| (*o, &d[..])).collect();
                    let rb: Vec<(Option<u64>, &[f32])> =
                        sb.iter().map(|(o, d)| (*o, &d[..])).collect();
                    self.scenes.push(ScoredScene::of(&ra, &rb));
                }
            }
        }
    }

    /// The scenes gathered.
    pub fn finish(mut self) -> Vec<ScoredScene> {
        self.flush();
        self.scenes
    }
}

/// Two views' sightings: the calibration's unit.
#[derive(Clone, Debug, Default)]
pub struct SightingPair {
    pub a: Vec<Sighting>,
    pub b: Vec<Sighting>,
}

/// Why a descriptor cannot be calibrated to its target.
#[derive(Debug, thiserror::Error)]
pub enum ReidError {
    #[error(
        "no object was seen by two connected vehicles at once on the validation runs: nothing to \
         calibrate the re-identification descriptor on"
    )]
    NoPairs,
    #[error(
        "the re-identification descriptor cannot reach rank-1 {target:.2} here: it ranges from \
         {low:.3} (noisiest) to {high:.3} (noise-free) on the validation runs"
    )]
    Rank1 { target: f64, low: f64, high: f64 },
    #[error(
        "the re-identification descriptor cannot reach AUROC {target:.2} at rank-1 {rank1:.2} \
         here: it ranges from {low:.3} to {high:.3} on the validation runs"
    )]
    Auroc {
        target: f64,
        rank1: f64,
        low: f64,
        high: f64,
    },
}

/// Each sighting's look, noise and view bias as dot products, so that
/// the cosine of any pair at any noise is arithmetic on numbers (the
/// draws are common to every noise tried: the figures move smoothly with
/// it).
struct Prepared {
    /// Per sighting: the noise's and the bias's scale at sigma = 1 and
    /// bias = 1, then l.l, l.e, e.e, l.c, e.c, c.c (look l, noise e,
    /// view bias c).
    own: Vec<[f64; 8]>,
    /// Per scene: its first sighting's index, its sizes, and per pair the
    /// nine products of (l, e, c) of a with (l, e, c) of b.
    scenes: Vec<(usize, usize, usize, Vec<[f64; 9]>)>,
    template: Vec<ScoredScene>,
}

fn dot(x: &[f64], y: &[f64]) -> f64 {
    x.iter().zip(y).map(|(a, b)| a * b).sum()
}

/// A sighting's look, noise and view bias.
type Parts = [Vec<f64>; 3];

impl Prepared {
    fn new(pairs: &[SightingPair], width: usize) -> Self {
        let unit = ReidNoise {
            sigma: 1.0,
            bias: 1.0,
        };
        let mut own = Vec::new();
        let mut scenes = Vec::new();
        let mut template = Vec::new();
        for p in pairs {
            let first = own.len();
            let parts = |side: &[Sighting]| -> Vec<Parts> {
                side.iter()
                    .map(|s| [look(s, width), noise(s, width), view_bias(s, width)])
                    .collect()
            };
            let (va, vb) = (parts(&p.a), parts(&p.b));
            for (s, [l, e, c]) in p.a.iter().zip(&va).chain(p.b.iter().zip(&vb)) {
                own.push([
                    noise_scale(s, unit),
                    bias_scale(s, unit),
                    dot(l, l),
                    dot(l, e),
                    dot(e, e),
                    dot(l, c),
                    dot(e, c),
                    dot(c, c),
                ]);
            }
            let mut dots = Vec::with_capacity(va.len() * vb.len());
            for x in &va {
                for y in &vb {
                    let mut d = [0.0; 9];
                    for (i, u) in x.iter().enumerate() {
                        for (j, v) in y.iter().enumerate() {
                            d[3 * i + j] = dot(u, v);
                        }
                    }
                    dots.push(d);
                }
            }
            scenes.push((first, p.a.len(), p.b.len(), dots));
            template.push(ScoredScene {
                a: p.a.iter().map(|s| s.object).collect(),
                b: p.b.iter().map(|s| s.object).collect(),
                cos: vec![0.0; p.a.len() * p.b.len()],
            });
        }
        Self {
            own,
            scenes,
            template,
        }
    }

    /// Sighting `k`'s weights of (look, noise, bias) at `n`, and its
    /// descriptor's length before scaling.
    fn weights(&self, k: usize, n: ReidNoise) -> ([f64; 3], f64) {
        let [ns, bs, ll, le, ee, lc, ec, cc] = self.own[k];
        let (s, b) = (n.sigma * ns, n.bias * bs);
        let sq = ll + s * s * ee + b * b * cc + 2.0 * (s * le + b * lc + s * b * ec);
        ([1.0, s, b], sq.max(1e-24).sqrt())
    }

    /// Every scene's cosines at `n`, written into `out`.
    fn score(&self, n: ReidNoise, out: &mut [ScoredScene]) {
        for ((first, na, nb, dots), scene) in self.scenes.iter().zip(out.iter_mut()) {
            let b: Vec<([f64; 3], f64)> =
                (0..*nb).map(|j| self.weights(first + na + j, n)).collect();
            for i in 0..*na {
                let (wa, la) = self.weights(first + i, n);
                for (j, (wb, lb)) in b.iter().enumerate() {
                    let d = &dots[i * nb + j];
                    let mut num = 0.0;
                    for x in 0..3 {
                        for y in 0..3 {
                            num += wa[x] * wb[y] * d[3 * x + y];
                        }
                    }
                    scene.cos[i * nb + j] = num / (la * lb);
                }
            }
        }
    }
}

/// Chooses the noise of the descriptor so that its figures on `pairs`
/// (the validation runs' views) meet `target`: the rank-1 rate by
/// bisection on `sigma` (it falls as the noise grows) at each bias
/// tried, the AUROC by bisection on the views' bias (which moves a whole
/// view's similarities together: it leaves each view's ranking nearly as
/// it was and mixes same-object pairs of one view with different-object
/// pairs of another). Returns the noise and the figures measured at it,
/// with the scored scenes (for the cosine's law).
pub fn calibrate(
    pairs: &[SightingPair],
    width: usize,
    target: ReidTarget,
) -> Result<(ReidNoise, ReidFigures, Vec<ScoredScene>), ReidError> {
    let shared = |p: &SightingPair| {
        p.a.iter()
            .any(|s| s.object.is_some() && p.b.iter().any(|t| t.object == s.object))
    };
    if !pairs.iter().any(shared) {
        return Err(ReidError::NoPairs);
    }
    let prepared = Prepared::new(pairs, width);
    let mut solver = Solver {
        scored: prepared.template.clone(),
        prepared: &prepared,
        target,
    };
    let noise = match target.auroc {
        None => solver.auroc_at(0.0)?.0,
        Some(goal) => solver.bias_for(goal)?,
    };
    let mut scored = solver.scored;
    prepared.score(noise, &mut scored);
    Ok((noise, figures(&scored), scored))
}

/// The searches of [`calibrate`], on one set of prepared views.
struct Solver<'a> {
    prepared: &'a Prepared,
    target: ReidTarget,
    /// Scratch: the scenes scored at the noise last tried.
    scored: Vec<ScoredScene>,
}

impl Solver<'_> {
    fn rank1_at(&mut self, n: ReidNoise) -> f64 {
        self.prepared.score(n, &mut self.scored);
        rank1(&self.scored).0
    }

    /// The `sigma` at which rank-1 is nearest its target with views'
    /// bias `bias`; an error when the target is out of reach.
    fn sigma_for(&mut self, bias: f64) -> Result<f64, ReidError> {
        let goal = self.target.rank1;
        let at = |ln: f64| ReidNoise {
            sigma: ln.exp(),
            bias,
        };
        let (ln_lo, ln_hi) = (1e-3f64.ln(), 1e3f64.ln());
        let high = self.rank1_at(at(ln_lo));
        let low = self.rank1_at(at(ln_hi));
        if !(low..=high).contains(&goal) {
            return Err(ReidError::Rank1 {
                target: goal,
                low,
                high,
            });
        }
        let (mut lo, mut hi) = (ln_lo, ln_hi);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if self.rank1_at(at(mid)) > goal {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        // Rank-1 moves in steps of one query: the side of the last step
        // nearer the target.
        let off_lo = (self.rank1_at(at(lo)) - goal).abs();
        let off_hi = (self.rank1_at(at(hi)) - goal).abs();
        Ok(if off_lo < off_hi { lo } else { hi }.exp())
    }

    /// The noise that meets the rank-1 target with views' bias `bias`,
    /// and the AUROC there.
    fn auroc_at(&mut self, bias: f64) -> Result<(ReidNoise, f64), ReidError> {
        let sigma = self.sigma_for(bias)?;
        let n = ReidNoise { sigma, bias };
        self.prepared.score(n, &mut self.scored);
        Ok((n, auroc(&mut labelled_pairs(&self.scored))))
    }

    /// The noise that meets both targets: bisection on the bias (the
    /// AUROC falls as it grows); a bias at which rank-1 is out of reach
    /// (a strong bias swamps the looks) counts as too strong.
    fn bias_for(&mut self, goal: f64) -> Result<ReidNoise, ReidError> {
        let (n0, high) = self.auroc_at(0.0)?;
        let (mut lo, mut hi) = (0.0, MAX_BIAS);
        let (mut best, mut low) = ((n0, high), high);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            match self.auroc_at(mid) {
                Ok((n, a)) => {
                    low = low.min(a);
                    if (a - goal).abs() < (best.1 - goal).abs() {
                        best = (n, a);
                    }
                    if a > goal {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                Err(_) => hi = mid,
            }
        }
        if (best.1 - goal).abs() > 0.01 * goal {
            return Err(ReidError::Auroc {
                target: goal,
                rank1: self.target.rank1,
                low,
                high,
            });
        }
        Ok(best.0)
    }
}

/// Gives every detection of `sensed` its descriptor at the calibrated
/// noise (`settings.calibration`; none before calibration, or when its
/// cosine tells nothing apart). The sender's own node, a V2X self-report,
/// carries none.
pub(crate) fn describe_detections(
    sensed: &mut Sensed,
    frame: &TrafficFrame,
    ego: usize,
    range_m: f64,
    seeds: (u64, u64),
    settings: &ReidSettings,
) {
    let Some(cal) = &settings.calibration else {
        return;
    };
    let Some(law) = cal.law else {
        return;
    };
    let seen = sightings(sensed, frame, ego, range_m, seeds);
    for ((det, truth), s) in sensed
        .observation
        .detections
        .iter_mut()
        .zip(&sensed.truth.detections)
        .zip(&seen)
    {
        if truth.sender {
            continue;
        }
        det.appearance.descriptor = Some(super::Descriptor {
            values: describe(s, settings.width, cal.noise).into(),
            law,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sighting(object: u64, model: u64, view_rad: f64, spoil: f64, noise_key: u64) -> Sighting {
        Sighting {
            object: Some(object),
            class: ObjectClass::Car,
            model_key: model,
            colour_rgb: [0.9, 0.9, 0.9],
            individual_key: object,
            view_rad,
            spoil,
            noise_key,
            view_key: noise_key / 1000,
        }
    }

    fn cos(a: &[f32], b: &[f32]) -> f64 {
        super::super::cosine(a, b)
    }

    /// A view from the side and one from behind describe one vehicle
    /// differently; two views from one side alike; another vehicle of
    /// the same model and paint, seen from the same side, is less alike
    /// than the vehicle itself from behind.
    #[test]
    fn a_side_view_and_a_rear_view_describe_one_vehicle_differently() {
        let quiet = ReidNoise {
            sigma: 0.0,
            bias: 0.0,
        };
        let w = 128;
        let side = describe(
            &sighting(1, 7, std::f64::consts::FRAC_PI_2, 0.2, 1),
            w,
            quiet,
        );
        let side_again = describe(
            &sighting(1, 7, -std::f64::consts::FRAC_PI_2, 0.9, 2),
            w,
            quiet,
        );
        let rear = describe(&sighting(1, 7, std::f64::consts::PI, 0.2, 3), w, quiet);
        let twin_side = describe(
            &sighting(2, 7, std::f64::consts::FRAC_PI_2, 0.2, 4),
            w,
            quiet,
        );
        assert!((cos(&side, &side_again) - 1.0).abs() < 1e-6);
        let side_rear = cos(&side, &rear);
        assert!(side_rear < 0.97, "{side_rear}");
        // Its own features still tell it from a twin of its model and
        // paint seen from the same side.
        let twin = cos(&side, &twin_side);
        assert!(twin < side_rear, "{twin} vs {side_rear}");
        // Noise: the same view twice is no longer identical, more so far
        // away.
        let noisy = ReidNoise {
            sigma: 0.3,
            bias: 0.0,
        };
        let near = cos(
            &describe(&sighting(1, 7, 1.0, 0.1, 5), w, noisy),
            &describe(&sighting(1, 7, 1.0, 0.1, 6), w, noisy),
        );
        let far = cos(
            &describe(&sighting(1, 7, 1.0, 1.8, 5), w, noisy),
            &describe(&sighting(1, 7, 1.0, 1.8, 6), w, noisy),
        );
        assert!(near < 0.999 && far < near, "{near} {far}");
    }

    /// Known scores give known figures: a partner strictly the most
    /// similar counts, a tie does not; AUROC by ranks, ties a half.
    #[test]
    fn figures_count_rank_one_and_auroc_by_hand() {
        let scene = ScoredScene {
            a: vec![Some(1), Some(2), None],
            b: vec![Some(1), Some(2)],
            // a1: b1 0.9, b2 0.5 (hit); a2: b1 0.7, b2 0.7 (tie: miss);
            // clutter 0.1, 0.2.
            cos: vec![0.9, 0.5, 0.7, 0.7, 0.1, 0.2],
        };
        let f = figures(&[scene]);
        // Queries: a1 (hit), a2 (tie), b1 (0.9 vs 0.7, 0.1: hit), b2 (0.7
        // vs 0.5, 0.2 but 0.7 ties with a2's? b2's partner is a2 at 0.7,
        // others a1 0.5 and clutter 0.2: hit).
        assert_eq!(f.queries, 4);
        assert!((f.rank1 - 0.75).abs() < 1e-12, "{}", f.rank1);
        // Positives 0.9, 0.7; negatives 0.5, 0.7, 0.1, 0.2: 0.9 beats 4,
        // 0.7 beats 3 and ties 1: (4 + 3.5) / 8.
        assert!((f.auroc - 7.5 / 8.0).abs() < 1e-12, "{}", f.auroc);
        assert!((f.candidates - 2.5).abs() < 1e-12);
    }

    /// Scenes of a few cars of a few models, seen from random angles and
    /// distances: calibration meets two different targets within 10 %,
    /// and its fast arithmetic agrees with describing each sighting.
    #[test]
    fn calibration_meets_two_targets_on_synthetic_views() {
        use rand::{Rng, SeedableRng};
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut pairs = Vec::new();
        for scene in 0..150u64 {
            let objects: Vec<u64> = (0..10).map(|k| scene * 100 + k).collect();
            let mut side = |flip: bool| -> Vec<Sighting> {
                let kept: Vec<u64> = objects
                    .iter()
                    .copied()
                    .filter(|_| r.random::<f64>() < 0.75)
                    .collect();
                kept.into_iter()
                    .map(|o| {
                        let mut s = sighting(
                            o,
                            o % 4,
                            r.random::<f64>() * std::f64::consts::TAU,
                            r.random::<f64>() * 1.5,
                            r.random(),
                        );
                        s.view_key = scene * 2 + u64::from(flip);
                        s.colour_rgb = [[0.95; 3], [0.1; 3], [0.45; 3]][(o % 3) as usize];
                        s
                    })
                    .collect()
            };
            let (a, b) = (side(false), side(true));
            pairs.push(SightingPair { a, b });
        }
        let w = 32;
        for target in [
            ReidTarget {
                rank1: 0.39,
                auroc: Some(0.67),
            },
            ReidTarget {
                rank1: 0.7,
                auroc: None,
            },
        ] {
            let (n, f, scored) = calibrate(&pairs, w, target).unwrap();
            assert!(
                (f.rank1 / target.rank1 - 1.0).abs() < 0.1,
                "{target:?}: {f:?}"
            );
            if let Some(a) = target.auroc {
                assert!((f.auroc / a - 1.0).abs() < 0.1, "{target:?}: {f:?}");
            }
            // The arithmetic agrees with the descriptors themselves.
            let p = &pairs[3];
            let da: Vec<Vec<f32>> = p.a.iter().map(|s| describe(s, w, n)).collect();
            let db: Vec<Vec<f32>> = p.b.iter().map(|s| describe(s, w, n)).collect();
            for (i, x) in da.iter().enumerate() {
                for (j, y) in db.iter().enumerate() {
                    let c = scored[3].cos[i * p.b.len() + j];
                    assert!((cos(x, y) - c).abs() < 1e-5, "{} vs {c}", cos(x, y));
                }
            }
        }
        // Below chance among the candidates: out of reach.
        let Err(e) = calibrate(
            &pairs,
            w,
            ReidTarget {
                rank1: 0.01,
                auroc: None,
            },
        ) else {
            panic!("rank-1 0.01 was reached");
        };
        assert!(e.to_string().contains("cannot reach rank-1"), "{e}");
    }
}
