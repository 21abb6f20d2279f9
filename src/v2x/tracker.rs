//! A connected vehicle's own multi-object tracker: each detection of its
//! camera becomes part of a track with a local id, a constant-velocity
//! Kalman filter (white-noise acceleration), gating on the Mahalanobis
//! distance and the appearance (class and chromaticity), the optimal
//! assignment, births from detections no track
//! takes, confirmation after a few hits and death after a coasting gap.
//! Ids break where a real tracker's would: an object hidden for longer
//! than the coasting gap comes back under a new id.
//!
//! Tracks live in the vehicle's tracking frame: the world frame as the
//! vehicle's odometry knows it (ego motion is taken as exact; the GNSS
//! error enters where positions are shared, not here). [`MotCounter`]
//! scores a tracker against the truth by the CLEAR-MOT rules.

use nalgebra::{Matrix2, Matrix2x4, Matrix4, Vector4};

use crate::assignment::assign;
use crate::geometry::{Cov2, Vec2};
use crate::traffic::ObjectClass;

/// `[v2x.tracker]`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerSettings {
    /// Standard deviation of the white-noise acceleration of the motion
    /// model (m/s²).
    pub accel_sigma_mps2: f64,
    /// Gate on the squared Mahalanobis distance of a detection to a
    /// track's predicted position (chi² with 2 degrees of freedom).
    pub gate_chi2: f64,
    /// Hits before a track is confirmed (and shared).
    pub confirm_hits: u32,
    /// A track not updated for this long is dropped (s).
    pub max_coast_s: f64,
    /// Standard deviation of a new track's velocity (m/s).
    pub birth_speed_sigma_mps: f64,
    /// The appearance term of the association cost: standard deviation of
    /// the difference between a detection's chromaticity (colour over
    /// brightness, which the lighting does not change) and its track's
    /// (the mean of its detections'); a detection whose class is neither
    /// the track's nor the one detectors confuse it with is gated out.
    /// 0: positions alone.
    pub appearance_sigma: f64,
    /// A dropped track is kept this much longer (s) to be re-identified:
    /// a detection no live track takes is matched against the dropped
    /// tracks (same gate and cost) before it starts a new track, and
    /// takes the old id back. 0: ids break at every gap longer than
    /// `max_coast_s`.
    pub reid_s: f64,
}

impl Default for TrackerSettings {
    fn default() -> Self {
        // Chosen on the validation runs (see `configs/default.toml`).
        Self {
            accel_sigma_mps2: 6.0,
            gate_chi2: 13.8,
            confirm_hits: 3,
            max_coast_s: 0.5,
            birth_speed_sigma_mps: 3.0,
            appearance_sigma: 0.2,
            reid_s: 0.0,
        }
    }
}

/// One detection in the tracking frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackMeasurement {
    pub position_m: Vec2,
    pub cov_m2: Cov2,
    pub class: ObjectClass,
    /// Observed colour, RGB in [0, 1].
    pub colour_rgb: [f64; 3],
}

/// Colour over brightness: what stays when the lighting scales a colour.
fn chromaticity(rgb: &[f64; 3]) -> [f64; 3] {
    let sum = rgb.iter().sum::<f64>().max(1e-6);
    rgb.map(|c| c / sum)
}

/// A track: state `(x, y, vx, vy)` in the tracking frame with its
/// covariance, as of `updated_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// Local id: constant while the vehicle tracks the object.
    pub id: u64,
    pub state: Vector4<f64>,
    pub cov: Matrix4<f64>,
    pub class: ObjectClass,
    /// The mean chromaticity of its detections.
    pub chromaticity: [f64; 3],
    pub born_s: f64,
    pub updated_s: f64,
    pub hits: u32,
}

impl Track {
    pub fn position_m(&self) -> Vec2 {
        Vec2::new(self.state[0], self.state[1])
    }

    pub fn velocity_mps(&self) -> Vec2 {
        Vec2::new(self.state[2], self.state[3])
    }

    pub fn position_cov_m2(&self) -> Cov2 {
        self.cov.fixed_view::<2, 2>(0, 0).into_owned()
    }

    pub fn velocity_cov_m2ps2(&self) -> Cov2 {
        self.cov.fixed_view::<2, 2>(2, 2).into_owned()
    }
}

/// Constant-velocity prediction over `dt_s` with white-noise acceleration
/// of standard deviation `accel_sigma_mps2`: exact for an object that
/// moves at constant velocity (the mean), with the covariance grown by
/// the discretised process noise.
pub fn predict(
    state: &Vector4<f64>,
    cov: &Matrix4<f64>,
    dt_s: f64,
    accel_sigma_mps2: f64,
) -> (Vector4<f64>, Matrix4<f64>) {
    let mut f = Matrix4::identity();
    f[(0, 2)] = dt_s;
    f[(1, 3)] = dt_s;
    let q = accel_sigma_mps2 * accel_sigma_mps2;
    let (t2, t3, t4) = (dt_s * dt_s, dt_s.powi(3), dt_s.powi(4));
    let mut qm = Matrix4::zeros();
    for axis in 0..2 {
        let (p, v) = (axis, axis + 2);
        qm[(p, p)] = t4 / 4.0 * q;
        qm[(p, v)] = t3 / 2.0 * q;
        qm[(v, p)] = t3 / 2.0 * q;
        qm[(v, v)] = t2 * q;
    }
    (f * state, f * cov * f.transpose() + qm)
}

/// The position rows of the state.
fn h() -> Matrix2x4<f64> {
    Matrix2x4::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
}

/// A vehicle's tracker.
#[derive(Clone, Debug)]
pub struct Tracker {
    settings: TrackerSettings,
    tracks: Vec<Track>,
    /// Dropped tracks still open to re-identification.
    lost: Vec<Track>,
    next_id: u64,
    time_s: Option<f64>,
}

impl Tracker {
    pub fn new(settings: TrackerSettings) -> Self {
        Self {
            settings,
            tracks: Vec::new(),
            lost: Vec::new(),
            next_id: 0,
            time_s: None,
        }
    }

    /// Tracks started so far (ids are 0, 1, ...).
    pub fn started(&self) -> u64 {
        self.next_id
    }

    /// Every live track (confirmed or not), as of the last step.
    pub fn tracks(&self) -> &[Track] {
        &self.tracks
    }

    /// The confirmed tracks, coasting ones included.
    pub fn confirmed(&self) -> impl Iterator<Item = &Track> {
        let hits = self.settings.confirm_hits;
        self.tracks.iter().filter(move |t| t.hits >= hits)
    }

    /// What the vehicle reports and shares: the confirmed tracks updated
    /// at the last step (a coasting track is kept for its id, not shown).
    pub fn reported(&self) -> impl Iterator<Item = &Track> {
        let now = self.time_s;
        self.confirmed()
            .filter(move |t| now.is_some_and(|n| (n - t.updated_s).abs() < 1e-9))
    }

    /// One step at `time_s` (not before the last): drops tracks not
    /// updated for longer than the coasting gap, predicts the others,
    /// assigns `measurements` to tracks (gated, optimal), updates the
    /// assigned and starts a track for each measurement left. Returns each
    /// measurement's track id.
    pub fn step(&mut self, time_s: f64, measurements: &[TrackMeasurement]) -> Vec<u64> {
        let dt = self.time_s.map_or(0.0, |t| (time_s - t).max(0.0));
        self.time_s = Some(time_s);
        let coast = self.settings.max_coast_s;
        let (live, dropped): (Vec<Track>, Vec<Track>) = std::mem::take(&mut self.tracks)
            .into_iter()
            .partition(|t| time_s - t.updated_s <= coast + 1e-9);
        self.tracks = live;
        let reid = self.settings.reid_s;
        self.lost.extend(dropped);
        self.lost
            .retain(|t| time_s - t.updated_s <= coast + reid + 1e-9);
        let sigma = self.settings.accel_sigma_mps2;
        for t in self.tracks.iter_mut().chain(self.lost.iter_mut()) {
            (t.state, t.cov) = predict(&t.state, &t.cov, dt, sigma);
        }
        let (n, m) = (self.tracks.len(), measurements.len());
        let mut scores = Vec::with_capacity(n * m);
        for t in &self.tracks {
            for z in measurements {
                scores.push(self.score(t, z));
            }
        }
        let mut ids = vec![u64::MAX; m];
        for (i, j) in assign(n, m, &scores) {
            update(&mut self.tracks[i], &measurements[j], time_s);
            ids[j] = self.tracks[i].id;
        }
        self.reidentify(measurements, &mut ids, time_s);
        for (j, z) in measurements.iter().enumerate() {
            if ids[j] == u64::MAX {
                ids[j] = self.birth(z, time_s);
            }
        }
        ids
    }

    /// The measurements no live track took (`ids[j]` unset), matched
    /// against the dropped tracks still open to re-identification: each
    /// one matched comes back to life with its id.
    fn reidentify(&mut self, measurements: &[TrackMeasurement], ids: &mut [u64], time_s: f64) {
        let free: Vec<usize> = (0..measurements.len())
            .filter(|&j| ids[j] == u64::MAX)
            .collect();
        if free.is_empty() || self.lost.is_empty() {
            return;
        }
        let mut scores = Vec::with_capacity(self.lost.len() * free.len());
        for t in &self.lost {
            for &j in &free {
                scores.push(self.score(t, &measurements[j]));
            }
        }
        let mut back: Vec<(usize, usize)> = assign(self.lost.len(), free.len(), &scores);
        back.sort_by_key(|&(i, _)| std::cmp::Reverse(i));
        for (i, k) in back {
            let mut t = self.lost.remove(i);
            update(&mut t, &measurements[free[k]], time_s);
            ids[free[k]] = t.id;
            self.tracks.push(t);
        }
    }

    /// The log-likelihood of `z` given track `t`'s prediction, or `None`
    /// outside the gate.
    fn score(&self, t: &Track, z: &TrackMeasurement) -> Option<f64> {
        let s: Matrix2<f64> = h() * t.cov * h().transpose() + z.cov_m2;
        let inv = s.try_inverse()?;
        let r = z.position_m - t.position_m();
        let d2 = (r.transpose() * inv * r)[0];
        if d2 > self.settings.gate_chi2 {
            return None;
        }
        let position = -0.5 * (d2 + s.determinant().max(1e-12).ln());
        let sigma = self.settings.appearance_sigma;
        if sigma <= 0.0 {
            return Some(position);
        }
        if z.class != t.class && z.class != t.class.confusable() && t.class != z.class.confusable()
        {
            return None;
        }
        let c = chromaticity(&z.colour_rgb);
        let dc2: f64 = (0..3).map(|k| (c[k] - t.chromaticity[k]).powi(2)).sum();
        Some(position - 0.5 * dc2 / (sigma * sigma))
    }

    fn birth(&mut self, z: &TrackMeasurement, time_s: f64) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        let v2 = self.settings.birth_speed_sigma_mps.powi(2);
        let mut cov = Matrix4::zeros();
        cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&z.cov_m2);
        cov[(2, 2)] = v2;
        cov[(3, 3)] = v2;
        self.tracks.push(Track {
            id,
            state: Vector4::new(z.position_m.x, z.position_m.y, 0.0, 0.0),
            cov,
            class: z.class,
            chromaticity: chromaticity(&z.colour_rgb),
            born_s: time_s,
            updated_s: time_s,
            hits: 1,
        });
        id
    }
}

/// The Kalman update of `t` with `z`.
fn update(t: &mut Track, z: &TrackMeasurement, time_s: f64) {
    let s: Matrix2<f64> = h() * t.cov * h().transpose() + z.cov_m2;
    let Some(inv) = s.try_inverse() else {
        return;
    };
    let k = t.cov * h().transpose() * inv;
    t.state += k * (z.position_m - t.position_m());
    // Joseph form, symmetrised: stays positive definite.
    let i_kh = Matrix4::identity() - k * h();
    let p = i_kh * t.cov * i_kh.transpose() + k * z.cov_m2 * k.transpose();
    t.cov = (p + p.transpose()) * 0.5;
    t.class = z.class;
    let c = chromaticity(&z.colour_rgb);
    let w = 1.0 / f64::from(t.hits + 1);
    for (m, ck) in t.chromaticity.iter_mut().zip(c) {
        *m += w * (ck - *m);
    }
    t.updated_s = time_s;
    t.hits += 1;
}

/// CLEAR-MOT counts over a vehicle's steps: misses, false tracks, id
/// switches, against the objects its camera could see.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotCounts {
    /// Visible objects summed over steps.
    pub ground_truth: usize,
    pub misses: usize,
    pub false_tracks: usize,
    pub id_switches: usize,
    /// Matched (object, track) pairs and their summed distance.
    pub matched: usize,
    pub distance_sum_m: f64,
}

impl MotCounts {
    pub fn add(&mut self, o: MotCounts) {
        self.ground_truth += o.ground_truth;
        self.misses += o.misses;
        self.false_tracks += o.false_tracks;
        self.id_switches += o.id_switches;
        self.matched += o.matched;
        self.distance_sum_m += o.distance_sum_m;
    }

    /// 1 - (misses + false tracks + id switches) / ground truth.
    pub fn mota(&self) -> f64 {
        if self.ground_truth == 0 {
            return f64::NAN;
        }
        let errors = self.misses + self.false_tracks + self.id_switches;
        1.0 - errors as f64 / self.ground_truth as f64
    }

    /// Mean distance of matched pairs (m).
    pub fn motp_m(&self) -> f64 {
        if self.matched == 0 {
            return f64::NAN;
        }
        self.distance_sum_m / self.matched as f64
    }
}

/// Scores one vehicle's tracker step by step (CLEAR-MOT): an object keeps
/// its track while they stay within the threshold; the rest are assigned
/// by distance; an object matched to another track than before is an id
/// switch.
#[derive(Clone, Debug, Default)]
pub struct MotCounter {
    threshold_m: f64,
    /// Each object's last matched track.
    last: std::collections::BTreeMap<String, u64>,
    pub counts: MotCounts,
}

impl MotCounter {
    pub fn new(threshold_m: f64) -> Self {
        Self {
            threshold_m,
            ..Self::default()
        }
    }

    /// One step: the visible objects (id, true position) and the confirmed
    /// tracks (id, position), both in the tracking frame.
    pub fn step(&mut self, objects: &[(String, Vec2)], tracks: &[(u64, Vec2)]) {
        let mut c = MotCounts {
            ground_truth: objects.len(),
            ..MotCounts::default()
        };
        let thr = self.threshold_m;
        let mut obj_match: Vec<Option<usize>> = vec![None; objects.len()];
        let mut track_used = vec![false; tracks.len()];
        // Keep last step's correspondences that still hold.
        for (i, (id, p)) in objects.iter().enumerate() {
            let Some(&tid) = self.last.get(id) else {
                continue;
            };
            if let Some(j) = tracks.iter().position(|t| t.0 == tid)
                && !track_used[j]
                && (tracks[j].1 - p).norm() <= thr
            {
                obj_match[i] = Some(j);
                track_used[j] = true;
            }
        }
        let free_o: Vec<usize> = (0..objects.len())
            .filter(|&i| obj_match[i].is_none())
            .collect();
        let free_t: Vec<usize> = (0..tracks.len()).filter(|&j| !track_used[j]).collect();
        let mut scores = Vec::with_capacity(free_o.len() * free_t.len());
        for &i in &free_o {
            for &j in &free_t {
                let d = (tracks[j].1 - objects[i].1).norm();
                scores.push((d <= thr).then_some(-d));
            }
        }
        for (a, b) in assign(free_o.len(), free_t.len(), &scores) {
            obj_match[free_o[a]] = Some(free_t[b]);
            track_used[free_t[b]] = true;
        }
        for (i, m) in obj_match.iter().enumerate() {
            let Some(j) = *m else {
                c.misses += 1;
                continue;
            };
            let (id, p) = &objects[i];
            let tid = tracks[j].0;
            if self.last.get(id).is_some_and(|&prev| prev != tid) {
                c.id_switches += 1;
            }
            self.last.insert(id.clone(), tid);
            c.matched += 1;
            c.distance_sum_m += (tracks[j].1 - p).norm();
        }
        c.false_tracks = track_used.iter().filter(|u| !**u).count();
        self.counts.add(c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn z(x: f64, y: f64) -> TrackMeasurement {
        TrackMeasurement {
            position_m: Vec2::new(x, y),
            cov_m2: Cov2::identity() * 0.04,
            class: ObjectClass::Car,
            colour_rgb: [0.5, 0.2, 0.2],
        }
    }

    /// The prediction's mean is exact for constant-velocity motion, and
    /// its covariance grows.
    #[test]
    fn prediction_is_exact_for_constant_velocity() {
        let x = Vector4::new(1.0, 2.0, 10.0, -3.0);
        let p = Matrix4::identity() * 0.1;
        let (x2, p2) = predict(&x, &p, 0.3, 2.0);
        assert!((x2 - Vector4::new(4.0, 1.1, 10.0, -3.0)).norm() < 1e-12);
        assert!(p2[(0, 0)] > p[(0, 0)] && p2[(2, 2)] > p[(2, 2)]);
        let (x0, p0) = predict(&x, &p, 0.0, 2.0);
        assert_eq!((x0, p0), (x, p));
    }

    /// Two objects crossing paths at 10 Hz keep their ids; the velocity is
    /// learned; an object hidden longer than the coasting gap comes back
    /// under a new id.
    #[test]
    fn tracks_keep_ids_learn_velocity_and_break_after_a_gap() {
        let mut t = Tracker::new(TrackerSettings::default());
        let mut first = Vec::new();
        for k in 0..30 {
            let s = k as f64 * 0.1;
            let ids = t.step(s, &[z(10.0 * s, 0.0), z(30.0 - 10.0 * s, 5.0)]);
            first.push(ids);
        }
        assert!(first.iter().all(|ids| ids == &first[0]), "{first:?}");
        let v = t.tracks()[0].velocity_mps();
        assert!((v - Vec2::new(10.0, 0.0)).norm() < 0.5, "{v:?}");
        assert_eq!(t.confirmed().count(), 2);
        // Hidden for 1.5 s (longer than the coasting gap): a new id.
        let ids = t.step(4.5, &[z(45.0, 0.0)]);
        assert!(!first[0].contains(&ids[0]));
    }

    /// An object hidden for 1 s (longer than the 0.5 s coasting gap)
    /// comes back under a new id, or, with re-identification open for
    /// 2 s, under its old one; a different object there does not take it.
    #[test]
    fn reidentification_gives_a_lost_object_its_id_back() {
        let run = |reid_s: f64, back: TrackMeasurement| {
            let mut t = Tracker::new(TrackerSettings {
                reid_s,
                ..TrackerSettings::default()
            });
            let mut id = 0;
            for k in 0..10 {
                let s = f64::from(k) * 0.1;
                id = t.step(s, &[z(10.0 * s, 0.0)])[0];
            }
            // Hidden from 1.0 s to 2.0 s: steps without it.
            for k in 10..20 {
                t.step(f64::from(k) * 0.1, &[]);
            }
            (id, t.step(2.0, &[back])[0])
        };
        let (before, after) = run(0.0, z(20.0, 0.0));
        assert_ne!(after, before);
        let (before, after) = run(2.0, z(20.0, 0.0));
        assert_eq!(after, before);
        let walker = TrackMeasurement {
            class: ObjectClass::Pedestrian,
            ..z(20.0, 0.0)
        };
        let (before, after) = run(2.0, walker);
        assert_ne!(after, before);
    }

    /// Two cars 1 m apart with noisy positions (sigma 2 m): when noise
    /// puts each where the other was, positions alone swap their ids; the
    /// appearance term keeps each id on its colour, whatever the
    /// brightness. A pedestrian next to a car never takes the car's track.
    #[test]
    fn appearance_keeps_ids_where_positions_swap_them() {
        let noisy = |x: f64, rgb: [f64; 3], class: ObjectClass| TrackMeasurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::identity() * 4.0,
            class,
            colour_rgb: rgb,
        };
        let (red, blue) = ([0.8, 0.1, 0.1], [0.1, 0.1, 0.8]);
        let car = ObjectClass::Car;
        let run = |appearance_sigma: f64| {
            let mut t = Tracker::new(TrackerSettings {
                appearance_sigma,
                ..TrackerSettings::default()
            });
            let before = t.step(0.0, &[noisy(0.0, red, car), noisy(1.0, blue, car)]);
            // Brighter light: the same colours, scaled.
            let dim = |c: [f64; 3]| c.map(|v| v * 1.2);
            let after = t.step(
                0.1,
                &[noisy(0.9, dim(red), car), noisy(0.1, dim(blue), car)],
            );
            (before, after)
        };
        let (before, after) = run(0.0);
        assert_eq!(after, [before[1], before[0]], "positions alone swap");
        let (before, after) = run(0.2);
        assert_eq!(after, before, "appearance keeps the ids");
        let mut t = Tracker::new(TrackerSettings::default());
        let cars = t.step(0.0, &[noisy(0.0, red, car)]);
        let walker = t.step(0.1, &[noisy(0.2, red, ObjectClass::Pedestrian)]);
        assert_ne!(walker, cars);
    }

    /// CLEAR-MOT on a hand-made sequence: one miss, one false track, one
    /// id switch over four object-steps.
    #[test]
    fn mot_counts_misses_false_tracks_and_switches() {
        let mut m = MotCounter::new(2.0);
        let a = |x: f64| ("a".to_owned(), Vec2::new(x, 0.0));
        m.step(&[a(0.0)], &[(1, Vec2::new(0.5, 0.0))]);
        m.step(&[a(1.0)], &[]);
        m.step(
            &[a(2.0)],
            &[(2, Vec2::new(2.0, 0.0)), (3, Vec2::new(9.0, 0.0))],
        );
        m.step(&[a(3.0)], &[(2, Vec2::new(3.0, 0.0))]);
        let c = m.counts;
        assert_eq!(
            (c.ground_truth, c.misses, c.false_tracks, c.id_switches),
            (4, 1, 1, 1)
        );
        assert!((c.mota() - 0.25).abs() < 1e-12);
        assert!((c.motp_m() - 0.5 / 3.0).abs() < 1e-12);
    }
}
