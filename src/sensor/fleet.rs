//! Which vehicles carry the rig (`[connected]`) and which of them
//! exchange detections (`comm_range_m`, `max_peers`).

use crate::geometry::Vec2;
use crate::rng::{self, Purpose};
use crate::traffic::TrafficObject;

/// `[connected]`: which vehicles carry the camera rig.
#[derive(Clone, Debug, PartialEq)]
pub enum ConnectedSelection {
    /// These SUMO vehicle ids carry the camera rig.
    Ids(Vec<String>),
    /// This share of the vehicles (cars, vans, trucks, buses), drawn per
    /// vehicle id from the sensor seed.
    Penetration(f64),
}

impl ConnectedSelection {
    /// Whether `obj` carries the rig (penetration draws are named by the
    /// vehicle id, so they do not depend on the order vehicles appear in).
    pub(crate) fn carries_rig(&self, sensor_seed: u64, obj: &TrafficObject) -> bool {
        match self {
            ConnectedSelection::Ids(ids) => ids.contains(&obj.id),
            ConnectedSelection::Penetration(p) => {
                obj.class.can_be_connected()
                    && rng::unit(sensor_seed, Purpose::Penetration, &[rng::hash_str(&obj.id)]) < *p
            }
        }
    }
}

/// `[connected] comm_range_m`, `max_peers`: which connected vehicles
/// exchange detections (a V2X link), from their true positions. Both unset
/// (the default): every pair does.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkSettings {
    /// Vehicles farther apart than this do not exchange (metres).
    pub(crate) comm_range_m: Option<f64>,
    /// Each vehicle exchanges with at most this many peers, nearest first
    /// (ties by position in the list): a pair is linked when each is among
    /// the other's nearest peers in range.
    pub(crate) max_peers: Option<usize>,
}

impl LinkSettings {
    /// The links among vehicles at `positions_m` (one frame's).
    pub(crate) fn links(&self, positions_m: &[Vec2]) -> Links {
        let n = positions_m.len();
        let dist = |i: usize, j: usize| (positions_m[i] - positions_m[j]).norm();
        let in_range = |i: usize, j: usize| self.comm_range_m.is_none_or(|r| dist(i, j) <= r);
        let mut linked = vec![false; n * n];
        for i in 0..n {
            let mut peers: Vec<usize> = (0..n).filter(|&j| j != i && in_range(i, j)).collect();
            if let Some(k) = self.max_peers {
                peers.sort_by(|&a, &b| dist(i, a).total_cmp(&dist(i, b)).then(a.cmp(&b)));
                peers.truncate(k);
            }
            for j in peers {
                linked[i * n + j] = true;
            }
        }
        Links { n, linked }
    }
}

/// Which vehicles of a frame exchange detections ([`LinkSettings::links`]).
#[derive(Clone, Debug)]
pub(crate) struct Links {
    n: usize,
    /// Row i: the peers i selected.
    linked: Vec<bool>,
}

impl Links {
    /// Whether `i` and `j` exchange detections (each selected the other).
    pub(crate) fn linked(&self, i: usize, j: usize) -> bool {
        self.linked[i * self.n + j] && self.linked[j * self.n + i]
    }
}
