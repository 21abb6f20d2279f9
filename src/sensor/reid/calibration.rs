//! The descriptor's figures and its calibration: every pair of two
//! views' detections scored by cosine ([`ScoredScene`]), the cross-view
//! rank-1 rate and the same/different AUROC ([`figures`]), and the noise
//! and view bias that meet their targets on the validation runs
//! ([`calibrate`]).

use super::*;
use crate::sensor::Sensed;

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
            .flat_map(|x| b.iter().map(|y| crate::sensor::cosine(x.1, y.1)))
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
        det.appearance.descriptor = Some(crate::sensor::Descriptor {
            values: describe(s, settings.width, cal.noise).into(),
            law,
        });
    }
}
