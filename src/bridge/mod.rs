//! The only module that touches pyo3: SUMO in-process through libsumo.
//!
//! `bridge/coid_bridge.py` (compiled into the binary) does the per-step
//! reads in Python; this module copies them into plain Rust structs under the
//! GIL and converts SUMO's conventions once: the front-bumper position
//! becomes the geometric centre, the navigational angle (0 = north,
//! clockwise, degrees) becomes a mathematical heading (0 = +x, counter-
//! clockwise, radians). Python exceptions become [`BridgeError`]s carrying
//! SUMO's message. SUMO is closed on every exit path ([`Drop`]).
//!
//! libsumo is a process-wide singleton: one [`Sumo`] per process at a time.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use pyo3::prelude::*;
use pyo3::types::PyModule;

use crate::geometry::{Polygon, Pose2, Vec2};
use crate::traffic::catalogue::Catalogue;
use crate::traffic::{
    Lane, ObjectClass, SUMO_DEFAULT_COLOUR, StaticScene, TrafficFrame, TrafficObject, UnsetColours,
    drawn_colour,
};

mod python;

use self::python::prepare_python;
pub use self::python::{netconvert, prepare_process, this_program};

const SHIM: &str = include_str!("../../bridge/coid_bridge.py");

/// Set while a simulation is open in this process.
static RUNNING: AtomicBool = AtomicBool::new(false);

#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error(
        "no Python environment with libsumo at {0} (remove it to have coid make it again, or set COID_VENV)"
    )]
    NoEnvironment(PathBuf),
    #[error("Python set-up failed: {0}")]
    Setup(String),
    #[error("SUMO failed to start with {sumocfg}: {message}")]
    Start { sumocfg: PathBuf, message: String },
    #[error("SUMO failed at t = {time_s} s: {message}")]
    Step { time_s: f64, message: String },
    #[error("SUMO call {call} failed: {message}")]
    Call { call: &'static str, message: String },
    #[error(
        "junction '{id}' does not exist in the scenario (it has {count} junctions, e.g. {examples})"
    )]
    UnknownJunction {
        id: String,
        count: usize,
        examples: String,
    },
    #[error("a SUMO simulation is already running in this process (libsumo allows one)")]
    AlreadyRunning,
    #[error("interrupted at t = {time_s} s")]
    Interrupted { time_s: f64 },
    #[error("SUMO's {tool} failed in {dir}: {message}")]
    Tool {
        tool: &'static str,
        dir: PathBuf,
        message: String,
    },
}

/// `TypeName: message` of a Python exception, on one line.
pub(super) fn describe(py: Python<'_>, err: &PyErr) -> String {
    let kind = err
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    let msg = err.value(py).to_string();
    let msg = msg.split_whitespace().collect::<Vec<_>>().join(" ");
    if msg.is_empty() {
        kind
    } else {
        format!("{kind}: {msg}")
    }
}

/// SUMO's report for a road user: front-bumper position (m), navigational
/// angle (deg, 0 = north, clockwise), length (m).
/// Returns the centre pose in the mathematical convention.
pub fn centre_pose_from_sumo(
    front_x_m: f64,
    front_y_m: f64,
    nav_angle_deg: f64,
    length_m: f64,
) -> Pose2 {
    let heading_rad = crate::geometry::wrap_angle((90.0 - nav_angle_deg).to_radians());
    let forward = Vec2::new(heading_rad.cos(), heading_rad.sin());
    Pose2::new(
        Vec2::new(front_x_m, front_y_m) - forward * (length_m / 2.0),
        heading_rad,
    )
}

/// Whether a SUMO polygon type is a building footprint.
pub fn is_building_type(t: &str) -> bool {
    t == "building" || t.starts_with("building.")
}

/// The junction `id` names among `ids`: itself, or the cluster netconvert
/// joined it into (`cluster_a_b_c` holds nodes a, b and c; ids may
/// themselves contain underscores, so the cluster's name must hold `_id_`
/// or end in `_id`).
pub fn resolve_junction<'a>(ids: &'a [String], id: &str) -> Option<&'a str> {
    if let Some(exact) = ids.iter().find(|j| *j == id) {
        return Some(exact);
    }
    if id.is_empty() {
        return None;
    }
    ids.iter()
        .filter(|j| j.starts_with("cluster"))
        .find(|j| j.contains(&format!("_{id}_")) || j.ends_with(&format!("_{id}")))
        .map(String::as_str)
}

/// One road user as the shim returns it:
/// `(id, vclass, (x, y, angle_nav_deg, speed, length, width, height), (r, g, b), type_id)`.
type Row = (
    String,
    String,
    (f64, f64, f64, f64, f64, f64, f64),
    (u8, u8, u8),
    String,
);

/// One lane as the shim returns it: `(id, width, shape)`.
type LaneRow = (String, f64, Vec<(f64, f64)>);

/// One polygon as the shim returns it: `(id, type, shape)`.
type PolygonRow = (String, String, Vec<(f64, f64)>);

/// What SUMO printed on standard error while loading (captured by the shim
/// into a file), on one line (empty when nothing).
fn captured_stderr(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// Closes libsumo after a failure (which also flushes SUMO's error log),
/// then describes the failure: what SUMO logged (often the only place that
/// says what went wrong: libsumo's exception may just say "Process Error"),
/// followed by the Python exception.
fn close_and_describe(py: Python<'_>, err: &PyErr, stderr_capture: &Path) -> String {
    let exc = describe(py, err);
    if let Ok(libsumo) = py.import("libsumo") {
        let _ = libsumo.call_method0("close");
    }
    let logged = captured_stderr(stderr_capture);
    if logged.is_empty() || exc.contains(&logged) {
        exc
    } else {
        format!("{logged} [{exc}]")
    }
}

/// Where SUMO's load errors are captured: `stderr.log` in a temporary
/// folder of this process (`coid-sumo-<pid>-XXXXXX`, an unpredictable
/// name), removed when the simulation is dropped and when the process is
/// interrupted; folders of processes that are gone (killed outright) are
/// removed when the next one is made.
struct Capture {
    _registered: crate::interrupt::Registered,
    dir: tempfile::TempDir,
}

impl Capture {
    const PREFIX: &str = "coid-sumo-";

    fn new() -> std::io::Result<Capture> {
        Self::remove_stale();
        let (dir, registered) = crate::interrupt::make_registered(|| {
            tempfile::Builder::new()
                .prefix(&format!("{}{}-", Self::PREFIX, std::process::id()))
                .tempdir()
        })?;
        Ok(Capture {
            _registered: registered,
            dir,
        })
    }

    fn path(&self) -> PathBuf {
        self.dir.path().join("stderr.log")
    }

    /// Removes the capture folders of processes that no longer run (the
    /// system's temporary folder is listed for them, and only for them).
    fn remove_stale() {
        let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(Self::PREFIX)) else {
                continue;
            };
            let pid = rest.split('-').next().and_then(|p| p.parse::<i32>().ok());
            if pid.is_some_and(|p| !crate::interrupt::process_runs(p)) && e.path().is_dir() {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

/// An open libsumo simulation.
pub struct Sumo {
    shim: Py<PyModule>,
    stderr_capture: Capture,
    time_s: f64,
    steps: u64,
    open: bool,
    /// The traffic seed colours are drawn with for road users whose
    /// demand gives none; `None` keeps SUMO's yellow.
    draw_colours: Option<u64>,
    /// The catalogue vehicles are drawn from, with the traffic seed
    /// (`None`: sizes and colours as the demand gives them).
    catalogue: Option<(std::sync::Arc<Catalogue>, u64)>,
}

impl Sumo {
    /// Starts SUMO on `sumocfg` with `--seed traffic_seed`, running until
    /// `end_s`, with `--step-length step_length_s` when given (else the
    /// sumocfg's step). Nothing is printed by SUMO but errors.
    pub fn start(
        sumocfg: &Path,
        traffic_seed: u64,
        end_s: f64,
        step_length_s: Option<f64>,
    ) -> Result<Sumo, BridgeError> {
        if RUNNING.swap(true, Ordering::SeqCst) {
            return Err(BridgeError::AlreadyRunning);
        }
        let stderr_capture = match Capture::new() {
            Ok(c) => c,
            Err(e) => {
                RUNNING.store(false, Ordering::SeqCst);
                return Err(BridgeError::Setup(format!(
                    "cannot make a file for SUMO's messages: {e}"
                )));
            }
        };
        let result = Python::attach(|py| -> Result<Sumo, BridgeError> {
            let shim = prepare_python(py)?;
            let mut args: Vec<String> = vec![
                "sumo".into(),
                "-c".into(),
                sumocfg.to_string_lossy().into_owned(),
                "--seed".into(),
                traffic_seed.to_string(),
                "--end".into(),
                format!("{end_s}"),
                "--no-step-log".into(),
                "true".into(),
                "--no-warnings".into(),
                "true".into(),
                "--duration-log.disable".into(),
                "true".into(),
            ];
            if let Some(step) = step_length_s {
                args.extend(["--step-length".into(), format!("{step}")]);
            }
            // The shim answers SUMO's step length; runs keep their own count.
            let _step_length_s: f64 = shim
                .call_method1(
                    "start",
                    (args, stderr_capture.path().to_string_lossy().into_owned()),
                )
                .and_then(|v| v.extract())
                .map_err(|e| BridgeError::Start {
                    sumocfg: sumocfg.to_owned(),
                    message: close_and_describe(py, &e, &stderr_capture.path()),
                })?;
            Ok(Sumo {
                shim: shim.unbind(),
                stderr_capture,
                time_s: 0.0,
                steps: 0,
                open: true,
                draw_colours: None,
                catalogue: None,
            })
        });
        if result.is_err() {
            RUNNING.store(false, Ordering::SeqCst);
        }
        result
    }

    /// How road users whose demand gives no colour look from now on:
    /// SUMO's yellow, or a colour drawn per id with `traffic_seed`
    /// ([`crate::traffic::drawn_colour`]).
    pub fn with_unset_colours(mut self, rule: UnsetColours, traffic_seed: u64) -> Self {
        self.draw_colours = (rule == UnsetColours::Drawn).then_some(traffic_seed);
        self
    }

    /// Vehicles from now on look like a model of `catalogue` in one of
    /// its paints, drawn by id and `traffic_seed`
    /// ([`Catalogue::draw`]): its length, width, height and colour replace
    /// the demand's (the pose stays SUMO's centre); road users of a class
    /// the catalogue lacks keep theirs.
    pub fn with_catalogue(
        mut self,
        catalogue: Option<std::sync::Arc<Catalogue>>,
        traffic_seed: u64,
    ) -> Self {
        self.catalogue = catalogue.map(|c| (c, traffic_seed));
        self
    }

    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    fn call<T>(
        &self,
        call: &'static str,
        args: impl for<'py> FnOnce(Python<'py>, &Bound<'py, PyModule>) -> PyResult<T>,
    ) -> Result<T, BridgeError> {
        Python::attach(|py| {
            let shim = self.shim.bind(py);
            args(py, shim).map_err(|e| BridgeError::Call {
                call,
                message: describe(py, &e),
            })
        })
    }

    /// The junction's position, or a clear error when it does not exist. A
    /// node that netconvert joined into a cluster (`--junctions.join`, OSM
    /// imports) is found as its cluster (`cluster_<id>_<id>...`).
    pub fn junction_position(&self, id: &str) -> Result<Vec2, BridgeError> {
        let ids: Vec<String> = self.call("junction_ids", |_, s| {
            s.call_method0("junction_ids")?.extract()
        })?;
        let Some(found) = resolve_junction(&ids, id) else {
            let named: Vec<&String> = ids.iter().filter(|j| !j.starts_with(':')).take(5).collect();
            return Err(BridgeError::UnknownJunction {
                id: id.to_owned(),
                count: ids.len(),
                examples: format!("{named:?}"),
            });
        };
        let (x, y): (f64, f64) = self.call("junction_position", |_, s| {
            s.call_method1("junction_position", (found,))?.extract()
        })?;
        Ok(Vec2::new(x, y))
    }

    /// Building footprints: polygons of SUMO type `building` or `building.*`
    /// (what polyconvert writes for OSM buildings: `building.yes`,
    /// `building.residential`, ...). A scenario without any is fine.
    pub fn buildings(&self) -> Result<Vec<Polygon>, BridgeError> {
        let polys: Vec<PolygonRow> =
            self.call("polygons", |_, s| s.call_method0("polygons")?.extract())?;
        Ok(polys
            .into_iter()
            .filter(|(_, t, shape)| is_building_type(t) && shape.len() >= 3)
            .map(|(_, _, shape)| Polygon {
                vertices_m: shape.into_iter().map(|(x, y)| Vec2::new(x, y)).collect(),
            })
            .collect())
    }

    /// Every lane's centre line and width (for pictures).
    pub fn lanes(&self) -> Result<Vec<Lane>, BridgeError> {
        let lanes: Vec<LaneRow> = self.call("lanes", |_, s| s.call_method0("lanes")?.extract())?;
        Ok(lanes
            .into_iter()
            .map(|(_, width_m, shape)| Lane {
                width_m,
                centre_m: shape.into_iter().map(|(x, y)| Vec2::new(x, y)).collect(),
            })
            .collect())
    }

    pub fn static_scene(&self, junction_id: &str) -> Result<StaticScene, BridgeError> {
        Ok(StaticScene {
            junction_id: junction_id.to_owned(),
            junction_position_m: self.junction_position(junction_id)?,
            buildings: self.buildings()?,
            lanes: self.lanes()?,
        })
    }

    /// Advances one step and returns every vehicle and person.
    pub fn step(&mut self) -> Result<TrafficFrame, BridgeError> {
        let time_before = self.time_s;
        if crate::interrupt::stop_requested() {
            return Err(BridgeError::Interrupted {
                time_s: time_before,
            });
        }
        let (time_s, _expected, rows) = Python::attach(|py| {
            let shim = self.shim.bind(py);
            shim.call_method0("step")
                .and_then(|v| v.extract::<(f64, i64, Vec<Row>)>())
                .map_err(|e| BridgeError::Step {
                    time_s: time_before,
                    message: close_and_describe(py, &e, &self.stderr_capture.path()),
                })
        })
        .inspect_err(|_| {
            // Already closed above; nothing left to close on drop.
            self.open = false;
            RUNNING.store(false, Ordering::SeqCst);
        })?;
        self.time_s = time_s;
        let step = self.steps;
        self.steps += 1;
        let objects = rows
            .into_iter()
            .map(
                |(id, vclass, (x, y, angle, speed, length, width, height), (r, g, b), type_id)| {
                    let class = ObjectClass::from_sumo_vclass(&vclass);
                    let colour_rgb = match self.draw_colours {
                        Some(seed) if [r, g, b] == SUMO_DEFAULT_COLOUR => {
                            drawn_colour(seed, &id, class)
                        }
                        _ => [r, g, b],
                    };
                    let mut object = TrafficObject {
                        type_id,
                        class,
                        pose: centre_pose_from_sumo(x, y, angle, length),
                        length_m: length,
                        width_m: width,
                        height_m: height,
                        colour_rgb,
                        speed_mps: speed,
                        model: None,
                        id,
                    };
                    if let Some((catalogue, seed)) = &self.catalogue
                        && let Some((m, paint)) = catalogue.draw(*seed, &object.id, class)
                    {
                        let [l, w, h] = catalogue.models[usize::from(m)].size_m;
                        (object.length_m, object.width_m, object.height_m) = (l, w, h);
                        object.colour_rgb = paint.rgb;
                        object.model = Some(m);
                    }
                    object
                },
            )
            .collect();
        Ok(TrafficFrame {
            step,
            time_s,
            objects,
        })
    }

    /// Closes SUMO, reporting an error if it fails.
    pub fn close(mut self) -> Result<(), BridgeError> {
        self.close_inner()
    }

    fn close_inner(&mut self) -> Result<(), BridgeError> {
        if !self.open {
            return Ok(());
        }
        self.open = false;
        let closed = self.call("close", |_, s| s.call_method0("close").map(|_| ()));
        RUNNING.store(false, Ordering::SeqCst);
        closed
    }
}

impl Drop for Sumo {
    fn drop(&mut self) {
        let _ = self.close_inner();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buildings_and_clustered_junctions_are_found_as_osm_imports_name_them() {
        assert!(is_building_type("building"));
        assert!(is_building_type("building.yes"));
        assert!(!is_building_type("buildings"));
        assert!(!is_building_type("landuse.residential"));
        let ids: Vec<String> = ["C", "cluster_12_345_6", ":C_0", "J7"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(resolve_junction(&ids, "C"), Some("C"));
        assert_eq!(resolve_junction(&ids, "345"), Some("cluster_12_345_6"));
        assert_eq!(resolve_junction(&ids, "6"), Some("cluster_12_345_6"));
        assert_eq!(
            resolve_junction(&ids, "cluster_12_345_6"),
            Some("cluster_12_345_6")
        );
        assert_eq!(resolve_junction(&ids, "34"), None);
        assert_eq!(resolve_junction(&ids, "Z9"), None);
    }

    #[test]
    fn sumo_front_bumper_and_nav_angle_become_centre_and_heading() {
        // Heading north (nav 0): centre is half a length south of the front.
        let p = centre_pose_from_sumo(10.0, 20.0, 0.0, 4.0);
        assert!((p.position_m() - Vec2::new(10.0, 18.0)).norm() < 1e-12);
        assert!((p.heading_rad() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // Heading east (nav 90): mathematical 0.
        let p = centre_pose_from_sumo(10.0, 20.0, 90.0, 4.0);
        assert!((p.position_m() - Vec2::new(8.0, 20.0)).norm() < 1e-12);
        assert!(p.heading_rad().abs() < 1e-12);
        // Heading south-west (nav 225): mathematical -135 deg.
        let p = centre_pose_from_sumo(0.0, 0.0, 225.0, 2.0 * 2f64.sqrt());
        assert!((p.position_m() - Vec2::new(1.0, 1.0)).norm() < 1e-12);
        assert!((p.heading_rad() + 0.75 * std::f64::consts::PI).abs() < 1e-12);
    }
}
