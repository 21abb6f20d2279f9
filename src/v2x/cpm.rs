//! Collective Perception Messages (after ETSI TS 103 324), as far as
//! correspondence identification needs them: what a message carries and
//! when a sender generates one and which of its tracks go in.
//!
//! Generation: a message at most every `1 / rate_hz` (bounded by
//! T_GenCpmMin = 0.1 s and T_GenCpmMax = 1 s); a confirmed track goes in
//! when it was never sent, or since it was last sent it moved more than
//! `position_change_m` (4 m), its speed changed by more than
//! `speed_change_mps` (0.5 m/s), its heading by more than
//! `heading_change_deg` (4 deg), or `max_interval_s` (1 s) passed. At
//! most `max_objects` go in, those waiting longest first.

use std::collections::BTreeMap;

use crate::geometry::{Cov2, Vec2};
use crate::traffic::ObjectClass;

/// `[v2x.cpm]`.
#[derive(Clone, Debug, PartialEq)]
pub struct CpmSettings {
    /// Generation rate (Hz), 1 to 10.
    pub rate_hz: f64,
    pub position_change_m: f64,
    pub speed_change_mps: f64,
    pub heading_change_deg: f64,
    /// An object is sent again at least this often (s).
    pub max_interval_s: f64,
    /// Objects per message at most.
    pub max_objects: usize,
}

impl Default for CpmSettings {
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            position_change_m: 4.0,
            speed_change_mps: 0.5,
            heading_change_deg: 4.0,
            max_interval_s: 1.0,
            max_objects: 64,
        }
    }
}

/// Below this speed an object has no heading to compare (m/s).
const HEADING_MIN_SPEED_MPS: f64 = 0.5;

/// One perceived object of a message: the sender's track, in the sender's
/// body frame at generation time.
#[derive(Clone, Debug, PartialEq)]
pub struct PerceivedObject {
    /// The sender's local track id.
    pub local_id: u64,
    pub position_m: Vec2,
    pub velocity_mps: Vec2,
    pub position_cov_m2: Cov2,
    pub velocity_cov_m2ps2: Cov2,
    /// Time the sender has tracked it (s).
    pub age_s: f64,
    pub class: ObjectClass,
}

/// What a generator needs of a track: id, position and velocity in the
/// sender's tracking frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackSnapshot {
    pub id: u64,
    pub position_m: Vec2,
    pub velocity_mps: Vec2,
}

/// A sender's generation state.
#[derive(Clone, Debug, Default)]
pub struct CpmGenerator {
    last_message_s: Option<f64>,
    /// Per track: when it was last sent and its state then.
    sent: BTreeMap<u64, (f64, TrackSnapshot)>,
}

impl CpmGenerator {
    /// Whether a message is due at `time_s`.
    pub fn due(&self, settings: &CpmSettings, time_s: f64) -> bool {
        let interval = (1.0 / settings.rate_hz).clamp(0.1, 1.0);
        self.last_message_s
            .is_none_or(|t| time_s - t >= interval - 1e-9)
    }

    /// The tracks of a message generated at `time_s` (ids, in the order
    /// given), recorded as sent. Call only when [`CpmGenerator::due`].
    pub fn select(
        &mut self,
        settings: &CpmSettings,
        time_s: f64,
        tracks: &[TrackSnapshot],
    ) -> Vec<u64> {
        self.last_message_s = Some(time_s);
        let mut wanted: Vec<(f64, usize)> = tracks
            .iter()
            .enumerate()
            .filter_map(|(k, t)| self.waiting(settings, time_s, t).map(|w| (w, k)))
            .collect();
        // Longest waiting first; ties in the given order.
        wanted.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        wanted.truncate(settings.max_objects);
        wanted.sort_by_key(|w| w.1);
        // Forget tracks that are gone.
        let live: std::collections::BTreeSet<u64> = tracks.iter().map(|t| t.id).collect();
        self.sent.retain(|id, _| live.contains(id));
        wanted
            .into_iter()
            .map(|(_, k)| {
                self.sent.insert(tracks[k].id, (time_s, tracks[k]));
                tracks[k].id
            })
            .collect()
    }

    /// How long `t` has waited to be sent (infinite when never sent), or
    /// `None` when no rule asks for it.
    fn waiting(&self, s: &CpmSettings, time_s: f64, t: &TrackSnapshot) -> Option<f64> {
        let Some((when, last)) = self.sent.get(&t.id) else {
            return Some(f64::INFINITY);
        };
        let waited = time_s - when;
        let moved = (t.position_m - last.position_m).norm() > s.position_change_m;
        let (v, v0) = (t.velocity_mps.norm(), last.velocity_mps.norm());
        let sped = (v - v0).abs() > s.speed_change_mps;
        let turned = v >= HEADING_MIN_SPEED_MPS
            && v0 >= HEADING_MIN_SPEED_MPS
            && angle_between(t.velocity_mps, last.velocity_mps).to_degrees() > s.heading_change_deg;
        let stale = waited >= s.max_interval_s - 1e-9;
        (moved || sped || turned || stale).then_some(waited)
    }
}

/// The unsigned angle between two vectors (rad).
fn angle_between(a: Vec2, b: Vec2) -> f64 {
    (a.x * b.y - a.y * b.x).atan2(a.dot(&b)).abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(id: u64, x: f64, vx: f64) -> TrackSnapshot {
        TrackSnapshot {
            id,
            position_m: Vec2::new(x, 0.0),
            velocity_mps: Vec2::new(vx, 0.0),
        }
    }

    /// At 10 Hz over 3 s: a parked car is sent once a second, a car at
    /// 50 m/s (5 m per message) every 100 ms, one at 10 m/s each time it
    /// moved more than 4 m (every 0.5 s).
    #[test]
    fn parked_cars_are_sent_once_a_second_fast_ones_every_message() {
        let s = CpmSettings::default();
        let mut g = CpmGenerator::default();
        let mut sent: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
        for k in 0..=30 {
            let t = f64::from(k) * 0.1;
            assert!(g.due(&s, t));
            let x = f64::from(k);
            let tracks = [at(1, 3.0, 0.0), at(2, 5.0 * x, 50.0), at(3, x, 10.0)];
            for id in g.select(&s, t, &tracks) {
                sent.entry(id).or_default().push((t * 10.0).round() / 10.0);
            }
        }
        assert_eq!(sent[&1], vec![0.0, 1.0, 2.0, 3.0]);
        assert_eq!(sent[&2].len(), 31);
        assert_eq!(sent[&3], vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]);
    }

    /// At 1 Hz a message is due once a second; the size limit keeps those
    /// waiting longest; a speed change or a turn triggers a resend.
    #[test]
    fn rate_size_limit_speed_and_heading_rules() {
        let s = CpmSettings {
            rate_hz: 1.0,
            max_objects: 2,
            ..CpmSettings::default()
        };
        let mut g = CpmGenerator::default();
        assert!(g.due(&s, 0.0));
        let tracks = [at(1, 0.0, 5.0), at(2, 10.0, 5.0), at(3, 20.0, 5.0)];
        assert_eq!(g.select(&s, 0.0, &tracks), vec![1, 2]);
        assert!(!g.due(&s, 0.5));
        assert!(g.due(&s, 1.0));
        // Track 3 never sent waits longest; 1 and 2 are stale (1 s).
        assert_eq!(g.select(&s, 1.0, &tracks), vec![1, 3]);
        let fast = CpmSettings {
            max_interval_s: 100.0,
            ..CpmSettings::default()
        };
        let mut g = CpmGenerator::default();
        g.select(&fast, 0.0, &[at(7, 0.0, 5.0)]);
        assert!(g.select(&fast, 0.1, &[at(7, 0.5, 5.4)]).is_empty());
        assert_eq!(g.select(&fast, 0.2, &[at(7, 1.0, 5.6)]), vec![7]);
        let turned = TrackSnapshot {
            velocity_mps: Vec2::new(5.6 * 0.99, 5.6 * 0.1),
            ..at(7, 1.1, 0.0)
        };
        assert_eq!(g.select(&fast, 0.3, &[turned]), vec![7]);
    }
}
