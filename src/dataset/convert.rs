//! `coid convert pyg`: PyTorch Geometric pair data as DMGM distributes it
//! (`<source>/proc_s/<k>/data.pt` and `<source>/proc_t/<k>/data.pt`, one
//! `Data` per view) into a dataset. Each view's fields:
//!
//! - `pos` [n, 3]: each detection in the camera frame (x right, y down,
//!   z forward, metres) -> body frame x forward = z, y left = -x;
//! - `pos_world` [n, 3], optional: the same through the vehicle's GPS
//!   pose, in CARLA's left-handed world (x, y on the ground, z up) ->
//!   `world_x_m` = x, `world_y_m` = -y (right-handed, as coid's world);
//! - `x` [n, d], optional: the appearance vector;
//! - `y` [n]: object ids (equal id, same object; once per view);
//! - `label` [n], optional: COCO class ids (person, bicycle, car,
//!   motorcycle, bus, truck);
//! - `name`, optional: `<...>/<recording>_<frame>`: pairs of one
//!   recording in one split make one run, the frame its instance's step.
//!
//! The pairs are read in index order; the split of each comes from index
//! ranges the user gives. Nothing of the `.pt` files is run
//! ([`crate::io::torch`]).

use std::ops::RangeInclusive;
use std::path::PathBuf;

use super::schema::{Edge, Instance, Node, Run, TruePair, Truth};
use crate::geometry::Vec2;
use crate::graph::SceneGraph;
use crate::io::torch::{self, DType, Field, Graph};
use crate::report::Table;

/// What a conversion reads and how it labels it.
pub struct PygSource {
    /// The folder holding one folder per view (`proc_s`, `proc_t`).
    pub dir: PathBuf,
    /// The views' folder names: the first and the second vehicle.
    pub views: [String; 2],
    /// Each split's pair indices, in order.
    pub splits: Vec<(String, RangeInclusive<u64>)>,
    /// The source's name (`dmgm`): runs are `<name>/<recording>`.
    pub name: String,
    /// The GPS accuracy the source's world positions were made with.
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
}

/// One pair's rows.
#[derive(Default)]
pub struct PairRows {
    pub instance: Vec<Instance>,
    pub nodes: Vec<Node>,
    pub edges: Vec<Edge>,
    pub truth: Vec<Truth>,
    pub true_pairs: Vec<TruePair>,
}

impl PairRows {
    /// The rows as each instance file's table, in file order.
    pub fn tables(self) -> [(&'static str, Table); 5] {
        [
            (Instance::FILE, Instance::table(self.instance)),
            (Node::FILE, Node::table(self.nodes)),
            (Edge::FILE, Edge::table(self.edges)),
            (Truth::FILE, Truth::table(self.truth)),
            (TruePair::FILE, TruePair::table(self.true_pairs)),
        ]
    }

    fn extend(&mut self, other: PairRows) {
        self.instance.extend(other.instance);
        self.nodes.extend(other.nodes);
        self.edges.extend(other.edges);
        self.truth.extend(other.truth);
        self.true_pairs.extend(other.true_pairs);
    }
}

/// A run of the conversion: its rows of `runs.parquet`.
pub struct ConvertedRun {
    pub split: String,
    pub scenario: String,
    pub n_instances: u64,
}

impl PygSource {
    /// Every pair of the splits, with its split, in index order: the
    /// first view's pair folders whose index lies in a split's range (a
    /// range is never walked index by index); refused when ranges overlap
    /// or a range holds no pair folder.
    pub fn pairs(&self) -> Result<Vec<(u64, &str)>, String> {
        for (i, (a, ra)) in self.splits.iter().enumerate() {
            for (b, rb) in &self.splits[i + 1..] {
                if ra.start() <= rb.end() && rb.start() <= ra.end() {
                    return Err(format!(
                        "the ranges of {a} ({}..{}) and {b} ({}..{}) overlap",
                        ra.start(),
                        ra.end(),
                        rb.start(),
                        rb.end()
                    ));
                }
            }
        }
        let dir = self.dir.join(&self.views[0]);
        let mut out: Vec<(u64, &str)> = Vec::new();
        for k in torch::numbered_folders(&dir)? {
            if let Some((split, _)) = self.splits.iter().find(|(_, r)| r.contains(&k)) {
                out.push((k, split.as_str()));
            }
        }
        out.sort_by_key(|&(k, _)| k);
        for (split, r) in &self.splits {
            if !out.iter().any(|(k, _)| r.contains(k)) {
                return Err(format!(
                    "no pair folder of {} lies in {split}={}..{}",
                    dir.display(),
                    r.start(),
                    r.end()
                ));
            }
        }
        Ok(out)
    }

    fn path(&self, view: usize, k: u64) -> PathBuf {
        self.dir
            .join(&self.views[view])
            .join(k.to_string())
            .join("data.pt")
    }

    /// Pair `k`'s two views, read and checked.
    pub fn read_pair(&self, k: u64) -> Result<[View; 2], String> {
        let view = |v: usize| -> Result<View, String> {
            let path = self.path(v, k);
            let graphs = torch::read_graphs(&path).map_err(|e| e.to_string())?;
            let [g] = graphs.as_slice() else {
                return Err(format!(
                    "{} holds {} graphs, not one view",
                    path.display(),
                    graphs.len()
                ));
            };
            View::of(g).map_err(|why| format!("{}: {why}", path.display()))
        };
        Ok([view(0)?, view(1)?])
    }
}

/// One vehicle's view of a pair, in coid's frames.
pub struct View {
    pub body_m: Vec<Vec2>,
    pub world_m: Vec<Vec2>,
    pub appearance: Option<Vec<Vec<f32>>>,
    /// Object ids; empty for an unknown object (an id < 0), never paired.
    pub ids: Vec<String>,
    pub classes: Vec<&'static str>,
    /// The recording and frame, from `name`.
    pub recording: Option<(String, u64)>,
}

/// A tensor field's shape, values and stored type.
type TensorRef<'g> = (&'g [usize], &'g [f64], DType);

fn tensor<'g>(g: &'g Graph, name: &str) -> Result<Option<TensorRef<'g>>, String> {
    match g.get(name) {
        None => Ok(None),
        Some(Field::Tensor {
            shape,
            values,
            dtype,
        }) => Ok(Some((shape, values, *dtype))),
        Some(_) => Err(format!("its '{name}' is not a tensor")),
    }
}

/// `n` rows of 3 finite floating-point columns (`n` from `y`).
fn points(g: &Graph, name: &str, n: usize) -> Result<Option<Vec<[f64; 3]>>, String> {
    let Some((shape, v, dtype)) = tensor(g, name)? else {
        return Ok(None);
    };
    if !dtype.is_float() {
        return Err(format!(
            "its '{name}' holds {} values, not floating point (positions in metres)",
            dtype.name()
        ));
    }
    if shape != [n, 3] {
        return Err(format!(
            "its '{name}' has shape {shape:?}, not [{n}, 3] (its 'y' names {n} objects: one row \
             per object)"
        ));
    }
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!("its '{name}' holds {} in row {}", v[k], k / 3));
    }
    Ok(Some(v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()))
}

/// Integer values (ids, class ids) of a tensor `name`: an integer type,
/// or floating point holding integers.
fn integers(name: &str, v: &[f64], dtype: DType) -> Result<Vec<i64>, String> {
    if dtype == DType::Bool {
        return Err(format!("its '{name}' holds bool values, not integers"));
    }
    v.iter()
        .enumerate()
        .map(|(k, &x)| {
            if x.is_finite() && x.fract() == 0.0 && x.abs() < 2f64.powi(53) {
                Ok(x as i64)
            } else {
                Err(format!("its '{name}' holds {x} in row {k}, not an integer"))
            }
        })
        .collect()
}

/// coid's class of a COCO class id.
fn coco_class(id: i64) -> Option<&'static str> {
    Some(match id {
        0 => "pedestrian",
        1 => "bicycle",
        2 => "car",
        3 => "motorcycle",
        5 => "bus",
        7 => "truck",
        _ => return None,
    })
}

/// The recording and frame a view's `name` gives (`<...>/<recording>_<frame>`).
fn recording(g: &Graph) -> Result<Option<(String, u64)>, String> {
    let name = match g.get("name") {
        None => return Ok(None),
        Some(Field::Text(name)) => name,
        Some(_) => return Err("its 'name' is not a text".into()),
    };
    let last = name.rsplit('/').next().unwrap_or(name);
    last.rsplit_once('_')
        .and_then(|(r, f)| Some((r, f.parse::<u64>().ok()?)))
        .filter(|(r, _)| !r.is_empty())
        .map(|(r, f)| Some((r.to_owned(), f)))
        .ok_or_else(|| {
            format!("its 'name' is {name:?}, not <...>/<recording>_<frame> (frame a number)")
        })
}

impl View {
    fn of(g: &Graph) -> Result<View, String> {
        let (shape, y, dtype) = tensor(g, "y")?.ok_or("it has no 'y' (object ids)")?;
        let [n] = *shape else {
            return Err(format!("its 'y' has shape {shape:?}, not [n]"));
        };
        let pos = points(g, "pos", n)?.ok_or("it has no 'pos' (camera-frame positions)")?;
        let body_m = pos.iter().map(|p| Vec2::new(p[2], -p[0])).collect();
        let world = points(g, "pos_world", n)?.ok_or(
            "it has no 'pos_world' (world positions, [n, 3]): coid fits each vehicle's pose to \
             them",
        )?;
        let world_m = world.iter().map(|p| Vec2::new(p[0], -p[1])).collect();
        let appearance = appearance(g, n)?;
        let mut ids: Vec<String> = Vec::with_capacity(n);
        for (k, id) in integers("y", y, dtype)?.into_iter().enumerate() {
            if id < 0 {
                ids.push(String::new());
                continue;
            }
            let id = id.to_string();
            if let Some(first) = ids.iter().position(|x| *x == id) {
                return Err(format!(
                    "its 'y' names object {id} twice (rows {first} and {k})"
                ));
            }
            ids.push(id);
        }
        let classes = match tensor(g, "label")? {
            None => vec!["car"; n],
            Some((shape, labels, dtype)) if shape == [n] => integers("label", labels, dtype)?
                .into_iter()
                .enumerate()
                .map(|(k, l)| {
                    coco_class(l).ok_or_else(|| {
                        format!("its 'label' holds COCO class {l} in row {k}, not a road user")
                    })
                })
                .collect::<Result<_, _>>()?,
            Some((shape, _, _)) => {
                return Err(format!(
                    "its 'label' has shape {shape:?}, not [{n}] (one class per object of 'y')"
                ));
            }
        };
        Ok(View {
            body_m,
            world_m,
            appearance,
            ids,
            classes,
            recording: recording(g)?,
        })
    }
}

/// The appearance vectors `x` [n, d], finite.
fn appearance(g: &Graph, n: usize) -> Result<Option<Vec<Vec<f32>>>, String> {
    let Some((shape, v, dtype)) = tensor(g, "x")? else {
        return Ok(None);
    };
    let &[rows, d] = shape else {
        return Err(format!("its 'x' has shape {shape:?}, not [{n}, d]"));
    };
    if rows != n || d == 0 {
        return Err(format!("its 'x' has shape {shape:?}, not [{n}, d]"));
    }
    if dtype == DType::Bool {
        return Err("its 'x' holds bool values, not numbers".into());
    }
    if let Some(k) = v
        .iter()
        .position(|x| !(x.is_finite() && x.abs() <= f64::from(f32::MAX)))
    {
        return Err(format!(
            "its 'x' holds {} in row {}, column {} (appearance values must be finite)",
            v[k],
            k / d,
            k % d
        ));
    }
    Ok(Some(
        v.chunks(d)
            .map(|c| c.iter().map(|&x| x as f32).collect())
            .collect(),
    ))
}

/// Accumulates the conversion: runs (a recording's consecutive pairs in
/// one split) and their instances' rows.
#[derive(Default)]
pub struct Converter {
    pub runs: Vec<ConvertedRun>,
    /// Pairs left out because a vehicle saw nothing: (index, view).
    pub skipped: Vec<(u64, String)>,
    pending: PairRows,
    width: Option<usize>,
    /// Whether the pairs have names (the first pair says).
    named: Option<bool>,
}

impl Converter {
    /// Adds pair `k` of `split` (its views `views`) as the next instance;
    /// a pair where a vehicle saw nothing is left out (and counted).
    pub fn add(
        &mut self,
        source: &PygSource,
        k: u64,
        split: &str,
        views: [View; 2],
    ) -> Result<(), String> {
        let recording = self.recording(source, k, &views)?;
        if let Some(v) = views.iter().position(|v| v.ids.is_empty()) {
            self.skipped.push((k, source.views[v].clone()));
            return Ok(());
        }
        let scenario = match &recording {
            Some((r, _)) => format!("{}/{r}", source.name),
            None => source.name.clone(),
        };
        let same_run = self
            .runs
            .last()
            .is_some_and(|r| r.split == split && r.scenario == scenario);
        if !same_run {
            self.runs.push(ConvertedRun {
                split: split.to_owned(),
                scenario,
                n_instances: 0,
            });
        }
        let run = (self.runs.len() - 1) as u64;
        let r = self.runs.last_mut().expect("pushed above");
        let instance = r.n_instances;
        r.n_instances += 1;
        for v in &views {
            if let Some(a) = &v.appearance {
                let d = a.first().map_or(0, Vec::len);
                match self.width {
                    Some(w) if d != 0 && w != d => {
                        return Err(format!(
                            "pair {k}: appearance vectors of {d} values, earlier pairs' of {w}"
                        ));
                    }
                    None if d != 0 => self.width = Some(d),
                    _ => {}
                }
            }
        }
        let step = recording.map_or(k, |(_, f)| f);
        let rows = pair_rows(source, (run, instance, step), &views)
            .map_err(|why| format!("pair {k}: {why}"))?;
        self.pending.extend(rows);
        Ok(())
    }

    /// Pair `k`'s recording and frame: both views name the same (or
    /// neither does), and every pair has a name or none has.
    fn recording(
        &mut self,
        source: &PygSource,
        k: u64,
        views: &[View; 2],
    ) -> Result<Option<(String, u64)>, String> {
        let [a, b] = [&views[0].recording, &views[1].recording];
        let shown = |r: &Option<(String, u64)>| match r {
            Some((r, f)) => format!("{r}_{f}"),
            None => "no name".to_owned(),
        };
        if a != b {
            return Err(format!(
                "pair {k}: its views name different frames ({} {}, {} {})",
                source.views[0],
                shown(a),
                source.views[1],
                shown(b)
            ));
        }
        match self.named {
            Some(named) if named != a.is_some() => Err(format!(
                "pair {k} has {} where earlier pairs have {} (coid groups pairs into runs by \
                 the recording their 'name' gives)",
                if named { "no 'name'" } else { "a 'name'" },
                if named { "one" } else { "none" }
            )),
            _ => {
                self.named = Some(a.is_some());
                Ok(a.clone())
            }
        }
    }

    /// Recordings whose pairs lie in more than one split, with the splits.
    pub fn split_recordings(&self) -> Vec<(String, Vec<String>)> {
        let mut by: std::collections::BTreeMap<&str, Vec<String>> = Default::default();
        for r in &self.runs {
            let splits = by.entry(r.scenario.as_str()).or_default();
            if !splits.contains(&r.split) {
                splits.push(r.split.clone());
            }
        }
        by.into_iter()
            .filter(|(_, s)| s.len() > 1)
            .map(|(r, s)| (r.to_owned(), s))
            .collect()
    }

    /// The rows held so far (no longer held).
    pub fn take(&mut self) -> PairRows {
        std::mem::take(&mut self.pending)
    }

    /// Node rows held.
    pub fn held(&self) -> usize {
        self.pending.nodes.len()
    }

    /// The runs' rows.
    pub fn run_table(&self, version: u64) -> Table {
        Run::table(
            self.runs
                .iter()
                .enumerate()
                .map(|(k, r)| Run {
                    schema_version: version,
                    run: k as u64,
                    split: r.split.clone(),
                    scenario: r.scenario.clone(),
                    // Nothing was drawn: the run's number keys the
                    // streams coid draws for it (the deep methods'
                    // dropout masks).
                    seed: k as u64,
                    n_instances: r.n_instances,
                    config_digest: String::new(),
                })
                .collect(),
        )
    }
}

/// One pair's rows: an instance at the level `gps` (the source's GPS
/// noise), each view's nodes, Delaunay edges and truth, and the true pairs
/// (equal object ids).
fn pair_rows(
    source: &PygSource,
    (run, instance, step): (u64, u64, u64),
    views: &[View; 2],
) -> Result<PairRows, String> {
    let mut rows = PairRows::default();
    rows.instance
        .push(instance_row(source, (run, instance, step), views));
    for (side, v) in views.iter().enumerate() {
        let side = side as u64;
        let graph = SceneGraph::delaunay(&v.body_m).map_err(|e| e.to_string())?;
        for (k, p) in v.body_m.iter().enumerate() {
            let world = v.world_m[k];
            rows.nodes.push(Node {
                run,
                instance,
                side,
                node: k as u64,
                x_m: p.x,
                y_m: p.y,
                cov_xx_m2: None,
                cov_xy_m2: None,
                cov_yy_m2: None,
                class: v.classes[k].to_owned(),
                colour_r: None,
                colour_g: None,
                colour_b: None,
                length_m: None,
                width_m: None,
                height_m: None,
                heading_rad: None,
                speed_mps: None,
                sender: None,
                world_x_m: Some(world.x),
                world_y_m: Some(world.y),
                appearance: v.appearance.as_ref().map(|a| a[k].clone()),
            });
            rows.truth.push(Truth {
                run,
                instance,
                side,
                node: k as u64,
                object_id: v.ids[k].clone(),
                true_x_m: None,
                true_y_m: None,
                visible_fraction: None,
            });
        }
        rows.edges.extend(graph.edges.iter().map(|e| Edge {
            run,
            instance,
            side,
            source: e.a as u64,
            target: e.b as u64,
            length_m: e.length_m,
        }));
    }
    for (a, id) in views[0].ids.iter().enumerate() {
        if id.is_empty() {
            continue;
        }
        if let Some(b) = views[1].ids.iter().position(|x| x == id) {
            rows.true_pairs.push(TruePair {
                run,
                instance,
                a: a as u64,
                b: b as u64,
            });
        }
    }
    Ok(rows)
}

/// A pair's instance row: the level `gps`, the source's GPS accuracy, no
/// reported or true poses (the nodes' world positions stand for them).
fn instance_row(
    source: &PygSource,
    (run, instance, step): (u64, u64, u64),
    views: &[View; 2],
) -> Instance {
    Instance {
        run,
        instance,
        pose_noise: "gps".to_owned(),
        step,
        time_s: None,
        first_id: source.views[0].clone(),
        second_id: source.views[1].clone(),
        n_first: views[0].ids.len() as u64,
        n_second: views[1].ids.len() as u64,
        first_x_m: None,
        first_y_m: None,
        first_heading_rad: None,
        second_x_m: None,
        second_y_m: None,
        second_heading_rad: None,
        position_sigma_m: source.position_sigma_m,
        first_heading_sigma_rad: source.heading_sigma_rad,
        second_heading_sigma_rad: source.heading_sigma_rad,
        first_true_x_m: None,
        first_true_y_m: None,
        first_true_heading_rad: None,
        second_true_x_m: None,
        second_true_y_m: None,
        second_true_heading_rad: None,
    }
}
