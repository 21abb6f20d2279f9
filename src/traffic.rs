//! What the traffic simulation hands to the rest of the program, in plain
//! Rust types: every road user's centre pose in the world frame (SUMO's net
//! frame, metres), its size, class and colour, and the static scene.
//!
//! SUMO's own conventions (front-bumper positions, navigational degrees) never
//! reach this module: the bridge converts them once.
//!
//! Also the scenario's settings (`[scenario]` of the config): which SUMO
//! scenario runs, for how long, around which junction.

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
    pub colour_rgb: [u8; 3],
    pub speed_mps: f64,
    /// SUMO's vehicle (or person) type id (`[detector] by_type` keys).
    pub type_id: String,
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
