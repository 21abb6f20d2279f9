//! What the traffic simulation hands to the rest of the program, in plain
//! Rust types: every road user's centre pose in the world frame (SUMO's net
//! frame, metres), its size, class and colour, and the static scene.
//!
//! SUMO's own conventions (front-bumper positions, navigational degrees) never
//! reach this module: the bridge converts them once.
//!
//! Also the scenario's settings (`[scenario]` of the config): which SUMO
//! scenario runs, for how long, around which junction.

pub mod catalogue;

use std::path::PathBuf;

use crate::geometry::{OrientedBox, Polygon, Pose2, Vec2};

/// `[scenario]`: what SUMO runs and where instances are taken.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioSettings {
    /// Absolute path of the `.sumocfg`.
    pub sumocfg: PathBuf,
    /// The SUMO junction id the study is centred on.
    pub junction: String,
    /// Simulated time at which the run stops.
    pub end_s: f64,
    /// Both connected vehicles must be this close to the junction centre for
    /// a (step, pair) to be an instance.
    pub radius_m: f64,
    /// Instances are taken at most this often (in simulated seconds).
    pub sample_every_s: f64,
}

crate::label_enum! { "object class";
    /// Road-user classes the sensor can tell apart (and sometimes confuses).
    #[strum(serialize_all = "lowercase")]
    pub enum ObjectClass {
        Car,
        Van,
        Truck,
        Bus,
        Motorcycle,
        Bicycle,
        Pedestrian,
    }
}

impl ObjectClass {
    pub const ALL: [ObjectClass; 7] = [
        ObjectClass::Car,
        ObjectClass::Van,
        ObjectClass::Truck,
        ObjectClass::Bus,
        ObjectClass::Motorcycle,
        ObjectClass::Bicycle,
        ObjectClass::Pedestrian,
    ];

    /// Maps a SUMO vehicle class to ours; anything unusual counts as a car.
    pub fn from_sumo_vclass(vclass: &str) -> Self {
        match vclass {
            "delivery" => ObjectClass::Van,
            "truck" | "trailer" => ObjectClass::Truck,
            "bus" | "coach" | "tram" => ObjectClass::Bus,
            "motorcycle" | "moped" => ObjectClass::Motorcycle,
            "bicycle" => ObjectClass::Bicycle,
            "pedestrian" => ObjectClass::Pedestrian,
            _ => ObjectClass::Car,
        }
    }

    /// The class a detector most often mistakes this one for.
    pub fn confusable(self) -> Self {
        match self {
            ObjectClass::Car => ObjectClass::Van,
            ObjectClass::Van => ObjectClass::Car,
            ObjectClass::Truck => ObjectClass::Bus,
            ObjectClass::Bus => ObjectClass::Truck,
            ObjectClass::Motorcycle => ObjectClass::Bicycle,
            ObjectClass::Bicycle => ObjectClass::Motorcycle,
            ObjectClass::Pedestrian => ObjectClass::Bicycle,
        }
    }

    /// Whether a vehicle of this class may carry a connected-vehicle camera
    /// rig when connected vehicles are drawn by penetration rate.
    pub fn can_be_connected(self) -> bool {
        matches!(
            self,
            ObjectClass::Car | ObjectClass::Van | ObjectClass::Truck | ObjectClass::Bus
        )
    }
}

/// The colour SUMO reports for a road user whose demand gives none (its
/// default yellow).
pub const SUMO_DEFAULT_COLOUR: [u8; 3] = [255, 255, 0];

crate::label_enum! { "unset-colour rule";
    /// `[sensor] unset_colours`: what a road user whose demand gives no
    /// colour ([`SUMO_DEFAULT_COLOUR`]) looks like.
    #[strum(serialize_all = "lowercase")]
    pub enum UnsetColours {
        /// A colour drawn per road user (by its id and the traffic seed)
        /// from published shares: [`VEHICLE_COLOURS`], [`PEOPLE_COLOURS`].
        Drawn,
        /// SUMO's yellow, as SUMO reports it.
        Sumo,
    }
}

/// New vehicles' paint colours, worldwide: Axalta's 70th Global Automotive
/// Color Popularity Report (2022 production; press release of 15 Dec
/// 2022): white 34 %, black 21 %, gray 19 %, blue 8 %, red 5 %, green 1 %
/// [pub]; silver 8 % derived as the achromatic share (82 %) minus white,
/// black and gray; the remaining 4 % ("other": brown, beige, yellow,
/// gold, not itemised) split 2/1/1 over brown, beige and yellow [assume].
/// The RGB values are those of the default intersection's vehicle types.
pub const VEHICLE_COLOURS: [([u8; 3], f64); 10] = [
    ([245, 245, 245], 0.34), // white
    ([20, 20, 20], 0.21),    // black
    ([110, 110, 115], 0.19), // gray
    ([190, 190, 195], 0.08), // silver
    ([30, 60, 150], 0.08),   // blue
    ([170, 20, 25], 0.05),   // red
    ([40, 100, 50], 0.01),   // green
    ([110, 80, 50], 0.02),   // brown
    ([210, 195, 160], 0.01), // beige
    ([230, 190, 30], 0.01),  // yellow
];

/// What pedestrians and cyclists wear, as a camera sees it [assume]: no
/// published distribution of clothing colours on streets was found (see
/// docs/detectors.md); dark and neutral clothing is taken to dominate, as
/// informal street counts report.
pub const PEOPLE_COLOURS: [([u8; 3], f64); 8] = [
    ([25, 25, 30], 0.35),    // black
    ([40, 50, 90], 0.15),    // dark blue, denim
    ([115, 115, 120], 0.15), // gray
    ([235, 235, 230], 0.10), // white
    ([120, 90, 60], 0.10),   // brown, beige
    ([170, 30, 40], 0.08),   // red
    ([50, 95, 60], 0.04),    // green
    ([230, 190, 40], 0.03),  // yellow
];

/// The colour a road user whose demand gives none is drawn: by its id and
/// the run's traffic seed, from [`PEOPLE_COLOURS`] for pedestrians and
/// cyclists and [`VEHICLE_COLOURS`] for everything else. A pure function
/// of its arguments: the same road user has the same colour at every step.
pub fn drawn_colour(traffic_seed: u64, id: &str, class: ObjectClass) -> [u8; 3] {
    let shares: &[([u8; 3], f64)] = match class {
        ObjectClass::Pedestrian | ObjectClass::Bicycle => &PEOPLE_COLOURS,
        _ => &VEHICLE_COLOURS,
    };
    let u = crate::rng::unit(
        traffic_seed,
        crate::rng::Purpose::Colour,
        &[crate::rng::hash_str(id)],
    );
    let mut acc = 0.0;
    for (rgb, p) in shares {
        acc += p;
        if u < acc {
            return *rgb;
        }
    }
    shares[shares.len() - 1].0
}

/// One road user at one time step.
#[derive(Clone, Debug, PartialEq)]
pub struct TrafficObject {
    /// SUMO's vehicle or person id; unique within a run.
    pub id: String,
    pub class: ObjectClass,
    /// Geometric centre and heading, world frame.
    pub pose: Pose2,
    pub length_m: f64,
    pub width_m: f64,
    pub height_m: f64,
    /// The demand's colour (the road user's own, else its type's), or one
    /// drawn if it gives none ([`UnsetColours`]).
    pub colour_rgb: [u8; 3],
    pub speed_mps: f64,
    /// SUMO's vehicle (or person) type id (`[detector] by_type` keys).
    pub type_id: String,
    /// The catalogue model it was drawn as (its index in the run's
    /// [`catalogue::Catalogue`]; `None`: its look is the demand's).
    pub model: Option<u16>,
}

impl TrafficObject {
    pub fn footprint(&self) -> OrientedBox {
        OrientedBox {
            pose: self.pose,
            length_m: self.length_m,
            width_m: self.width_m,
        }
    }
}

/// Every road user at one simulation step.
#[derive(Clone, Debug, PartialEq)]
pub struct TrafficFrame {
    /// Step index since the start of the run (0 for the first step taken).
    pub step: u64,
    pub time_s: f64,
    pub objects: Vec<TrafficObject>,
}

impl TrafficFrame {
    pub fn find(&self, id: &str) -> Option<usize> {
        self.objects.iter().position(|o| o.id == id)
    }
}

/// A lane's centre line (world frame) and width, for pictures.
#[derive(Clone, Debug, PartialEq)]
pub struct Lane {
    pub width_m: f64,
    pub centre_m: Vec<Vec2>,
}

/// What does not move: the junction under study, the building footprints
/// and the lanes.
#[derive(Clone, Debug, PartialEq)]
pub struct StaticScene {
    pub junction_id: String,
    pub junction_position_m: Vec2,
    pub buildings: Vec<Polygon>,
    pub lanes: Vec<Lane>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drawn_colours_follow_their_published_shares_and_stay_with_their_id() {
        for shares in [&VEHICLE_COLOURS[..], &PEOPLE_COLOURS[..]] {
            let total: f64 = shares.iter().map(|s| s.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "{total}");
        }
        let n = 40_000;
        for (class, shares) in [
            (ObjectClass::Car, &VEHICLE_COLOURS[..]),
            (ObjectClass::Pedestrian, &PEOPLE_COLOURS[..]),
        ] {
            let colours: Vec<[u8; 3]> = (0..n)
                .map(|k| drawn_colour(3, &format!("f.{k}"), class))
                .collect();
            for (rgb, p) in shares {
                let share = colours.iter().filter(|c| *c == rgb).count() as f64 / n as f64;
                assert!(
                    (share - p).abs() < 0.01,
                    "{class:?} {rgb:?}: {share} vs {p}"
                );
            }
        }
        assert_eq!(
            drawn_colour(3, "veh7", ObjectClass::Car),
            drawn_colour(3, "veh7", ObjectClass::Car)
        );
        let differs = (0..50).any(|k| {
            drawn_colour(3, &format!("v{k}"), ObjectClass::Car)
                != drawn_colour(4, &format!("v{k}"), ObjectClass::Car)
        });
        assert!(differs, "the traffic seed takes part");
    }
}
