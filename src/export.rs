//! `coid export` and `coid score`: every instance of a configuration as
//! Parquet tables for matchers written elsewhere (schema:
//! `docs/export-schema.md`, [`SCHEMA_VERSION`]), and correspondences made
//! elsewhere read back as one more method, checked against the instances
//! they name.
//!
//! Runs are numbered once for a configuration ([`runs`]: training, then
//! validation, then test runs), whatever is exported, so that a matches
//! file names the same run in every export of the same configuration.

use std::collections::{BTreeMap, BTreeSet};

use crate::config::Settings;
use crate::evaluate::{ExternalMatches, FrameEval, PairAtLevel, Side};
use crate::experiments;
use crate::io::{OutputError, TablesFolder};
use crate::matching::{Correspondence, Method, binary_entropy_bits, oracle};
use crate::pipeline::{self, Instance, Progress, RunError};
use crate::report::{MatchRow, Table};
use crate::sensor::PoseNoiseLabel;

/// The version of the export's columns (`runs.parquet` carries it): 2
/// added `config_digest`.
pub const SCHEMA_VERSION: u64 = 2;

/// The schema, written beside the files as `schema.md`.
pub const SCHEMA: &str = include_str!("../docs/export-schema.md");

crate::label_enum! { "split";
    /// What a run may be used for.
    pub enum Split {
        #[strum(serialize = "train")]
        Train,
        #[strum(serialize = "validation")]
        Validation,
        #[strum(serialize = "test")]
        Test,
    }
}

/// One run of a configuration, numbered for export and scoring.
pub struct ExportRun {
    pub index: usize,
    pub split: Split,
    /// The SUMO configuration, as `<folder>/<file stem>`.
    pub scenario: String,
    pub seed: u64,
    pub settings: Settings,
}

/// Every run of `settings`: the training runs (instances sampled as
/// training samples them), the validation runs, the test runs (as `coid
/// eval` runs them), numbered in that order.
pub fn runs(settings: &Settings) -> Result<Vec<ExportRun>, RunError> {
    let splits = [
        (Split::Train, experiments::training_runs(settings)?),
        (Split::Validation, experiments::validation_runs(settings)?),
        (Split::Test, experiments::test_runs(settings)?),
    ];
    let mut out = Vec::new();
    for (split, runs) in splits {
        for s in runs {
            let cfg = &s.scenario.sumocfg;
            let name = |p: Option<&std::ffi::OsStr>| p.map(|n| n.to_string_lossy().into_owned());
            let folder = name(cfg.parent().and_then(|p| p.file_name())).unwrap_or_default();
            let stem = name(cfg.file_stem()).unwrap_or_default();
            out.push(ExportRun {
                index: out.len(),
                split,
                scenario: format!("{folder}/{stem}"),
                seed: s.seeds.traffic,
                settings: s,
            });
        }
    }
    Ok(out)
}

/// The export's Parquet files of instances, each with its (empty) columns.
pub fn files() -> Vec<(&'static str, Table)> {
    let mut rows = Rows::default();
    let mut f = vec![("runs.parquet", run_table(&[], ""))];
    f.extend(COLUMNS.iter().map(|(file, _)| (*file, rows.take(file))));
    f
}

/// The file of a method's matches (`--with-matches`).
pub fn matches_file(method: Method) -> String {
    format!("matches-{}.parquet", method.as_str())
}

/// The columns of a matches file, for an empty one.
pub fn matches_template() -> Table {
    MatchColumns::default().table()
}

/// The `runs.parquet` rows of `runs` (with their instance counts), of the
/// configuration whose instances digest is `digest`
/// ([`Settings::instances_digest`]).
pub fn run_table(runs: &[(&ExportRun, usize)], digest: &str) -> Table {
    let mut t = Table::default();
    t.count("schema_version", vec![SCHEMA_VERSION; runs.len()]);
    t.count("run", runs.iter().map(|r| r.0.index as u64).collect());
    t.text(
        "split",
        runs.iter().map(|r| r.0.split.as_str().into()).collect(),
    );
    t.text(
        "scenario",
        runs.iter().map(|r| r.0.scenario.clone()).collect(),
    );
    t.count("seed", runs.iter().map(|r| r.0.seed).collect());
    t.count("n_instances", runs.iter().map(|r| r.1 as u64).collect());
    t.text("config_digest", vec![digest.to_owned(); runs.len()]);
    t
}

/// Exports one run into `out`: its instances, nodes, edges, truth and true
/// pairs, and the matches of each of `methods` (files
/// [`matches_file`]); returns its instance count.
pub fn export_run(
    run: &ExportRun,
    methods: &[Method],
    threads: usize,
    progress: impl FnMut(Progress),
    out: &mut TablesFolder,
) -> Result<usize, RunError> {
    let s = &run.settings;
    // The oracle's pass makes the instance files; its matches, if asked
    // for, come from the same pass.
    let mut runners = vec![crate::evaluate::Runner::Oracle];
    let others: Vec<Method> = methods
        .iter()
        .copied()
        .filter(|&m| m != Method::Oracle)
        .collect();
    runners.extend(pipeline::runners(s, &others)?);
    let oracle_matches = methods.contains(&Method::Oracle);
    let first_level = s.pose_noise.first().map(|l| l.label);
    let mut rows = Rows::default();
    let mut matches: BTreeMap<Method, MatchColumns> = BTreeMap::new();
    let on_eval = |insts: &[Instance], pairs: &[PairAtLevel], level, f: FrameEval| {
        if f.method == Method::Oracle {
            if oracle_matches {
                matches
                    .entry(Method::Oracle)
                    .or_default()
                    .add(run.index, pairs, &f);
            }
            if Some(level) == first_level {
                rows.add_nodes(run.index, insts, pairs);
            }
            rows.add_instances(run.index, insts, pairs);
            if rows.held >= ROWS_PER_GROUP {
                rows.write(out)?;
            }
        } else {
            matches
                .entry(f.method)
                .or_default()
                .add(run.index, pairs, &f);
        }
        Ok(())
    };
    let stats = pipeline::evaluate_frames(s, &runners, threads, progress, on_eval)?;
    rows.write(out)?;
    for (method, m) in &matches {
        out.write(&matches_file(*method), &m.table())?;
    }
    Ok(stats.n_instances)
}

/// Rows held before they are written as row groups.
const ROWS_PER_GROUP: usize = 65_536;

/// The rows of the export's instance files, held as columns until written.
#[derive(Default)]
struct Rows {
    counts: BTreeMap<(&'static str, &'static str), Vec<u64>>,
    numbers: BTreeMap<(&'static str, &'static str), Vec<f64>>,
    texts: BTreeMap<(&'static str, &'static str), Vec<String>>,
    flags: BTreeMap<(&'static str, &'static str), Vec<bool>>,
    /// Node rows held.
    held: usize,
}

/// One method's matches, as columns.
#[derive(Default)]
struct MatchColumns {
    run: Vec<u64>,
    instance: Vec<u64>,
    pose_noise: Vec<String>,
    a: Vec<u64>,
    b: Vec<u64>,
    probability: Vec<f64>,
    uncertainty: Vec<f64>,
}

impl MatchColumns {
    /// A frame's decided matches at one level.
    fn add(&mut self, run: usize, pairs: &[PairAtLevel], f: &FrameEval) {
        for (pair, e) in pairs.iter().zip(&f.pairs) {
            for c in &e.identification.matches {
                self.run.push(run as u64);
                self.instance.push(pair.instance as u64);
                self.pose_noise.push(pair.level.label.as_str().to_owned());
                self.a.push(c.a as u64);
                self.b.push(c.b as u64);
                self.probability.push(c.probability);
                self.uncertainty.push(c.uncertainty);
            }
        }
    }

    fn table(&self) -> Table {
        let mut t = Table::default();
        t.count("run", self.run.clone());
        t.count("instance", self.instance.clone());
        t.text("pose_noise", self.pose_noise.clone());
        t.count("a", self.a.clone());
        t.count("b", self.b.clone());
        t.number("probability", self.probability.clone());
        t.number("uncertainty", self.uncertainty.clone());
        t
    }
}

/// Each file's columns in order: (name, kind: c count, n number, t text,
/// f flag).
const COLUMNS: [(&str, &[(&str, char)]); 5] = [
    (
        "instances.parquet",
        &[
            ("run", 'c'),
            ("instance", 'c'),
            ("pose_noise", 't'),
            ("step", 'c'),
            ("time_s", 'n'),
            ("first_id", 't'),
            ("second_id", 't'),
            ("n_first", 'c'),
            ("n_second", 'c'),
            ("first_x_m", 'n'),
            ("first_y_m", 'n'),
            ("first_heading_rad", 'n'),
            ("second_x_m", 'n'),
            ("second_y_m", 'n'),
            ("second_heading_rad", 'n'),
            ("position_sigma_m", 'n'),
            ("heading_sigma_rad", 'n'),
        ],
    ),
    (
        "nodes.parquet",
        &[
            ("run", 'c'),
            ("instance", 'c'),
            ("side", 'c'),
            ("node", 'c'),
            ("x_m", 'n'),
            ("y_m", 'n'),
            ("cov_xx_m2", 'n'),
            ("cov_xy_m2", 'n'),
            ("cov_yy_m2", 'n'),
            ("class", 't'),
            ("colour_r", 'n'),
            ("colour_g", 'n'),
            ("colour_b", 'n'),
            ("length_m", 'n'),
            ("width_m", 'n'),
            ("height_m", 'n'),
            ("sender", 'f'),
        ],
    ),
    (
        "edges.parquet",
        &[
            ("run", 'c'),
            ("instance", 'c'),
            ("side", 'c'),
            ("source", 'c'),
            ("target", 'c'),
            ("length_m", 'n'),
        ],
    ),
    (
        "truth.parquet",
        &[
            ("run", 'c'),
            ("instance", 'c'),
            ("side", 'c'),
            ("node", 'c'),
            ("object_id", 't'),
            ("true_x_m", 'n'),
            ("true_y_m", 'n'),
            ("visible_fraction", 'n'),
        ],
    ),
    (
        "true_pairs.parquet",
        &[("run", 'c'), ("instance", 'c'), ("a", 'c'), ("b", 'c')],
    ),
];

impl Rows {
    /// The held columns of `file` as a table (no longer held).
    fn take(&mut self, file: &'static str) -> Table {
        let mut t = Table::default();
        let spec = COLUMNS
            .iter()
            .find(|c| c.0 == file)
            .map_or(&[][..], |c| c.1);
        for &(name, kind) in spec {
            let key = (file, name);
            match kind {
                'c' => t.count(name, self.counts.remove(&key).unwrap_or_default()),
                'n' => t.number(name, self.numbers.remove(&key).unwrap_or_default()),
                't' => t.text(name, self.texts.remove(&key).unwrap_or_default()),
                _ => t.flag(name, self.flags.remove(&key).unwrap_or_default()),
            }
        }
        t
    }

    fn c(&mut self, file: &'static str, name: &'static str, v: u64) {
        self.counts.entry((file, name)).or_default().push(v);
    }

    fn n(&mut self, file: &'static str, name: &'static str, v: f64) {
        self.numbers.entry((file, name)).or_default().push(v);
    }

    fn t(&mut self, file: &'static str, name: &'static str, v: &str) {
        self.texts
            .entry((file, name))
            .or_default()
            .push(v.to_owned());
    }

    /// One row per instance at this level: the reported poses.
    fn add_instances(&mut self, run: usize, insts: &[Instance], pairs: &[PairAtLevel]) {
        const F: &str = "instances.parquet";
        for (inst, pair) in insts.iter().zip(pairs) {
            self.c(F, "run", run as u64);
            self.c(F, "instance", inst.index as u64);
            self.t(F, "pose_noise", pair.level.label.as_str());
            self.c(F, "step", inst.frame.step);
            self.n(F, "time_s", inst.frame.time_s);
            self.t(F, "first_id", &pair.first.obs.ego_id);
            self.t(F, "second_id", &pair.second.obs.ego_id);
            self.c(F, "n_first", pair.first.obs.detections.len() as u64);
            self.c(F, "n_second", pair.second.obs.detections.len() as u64);
            for (side, names) in [
                (&pair.first, ["first_x_m", "first_y_m", "first_heading_rad"]),
                (
                    &pair.second,
                    ["second_x_m", "second_y_m", "second_heading_rad"],
                ),
            ] {
                let pose = side.view.pose_reported;
                self.n(F, names[0], pose.position_m().x);
                self.n(F, names[1], pose.position_m().y);
                self.n(F, names[2], pose.heading_rad());
            }
            self.n(F, "position_sigma_m", pair.level.position_sigma_m);
            self.n(F, "heading_sigma_rad", pair.level.heading_sigma_rad);
        }
    }

    /// Both vehicles' nodes, edges and truth, and the true pairs, of each
    /// instance.
    fn add_nodes(&mut self, run: usize, insts: &[Instance], pairs: &[PairAtLevel]) {
        for (inst, pair) in insts.iter().zip(pairs) {
            let key = [run as u64, inst.index as u64];
            for (side, s) in [&pair.first, &pair.second].into_iter().enumerate() {
                self.add_side(key, side as u64, s);
            }
            for c in oracle::true_pairs(pair.first.truth, pair.second.truth) {
                const F: &str = "true_pairs.parquet";
                self.c(F, "run", key[0]);
                self.c(F, "instance", key[1]);
                self.c(F, "a", c.a as u64);
                self.c(F, "b", c.b as u64);
            }
        }
    }

    fn add_side(&mut self, [run, instance]: [u64; 2], side: u64, s: &Side) {
        const N: &str = "nodes.parquet";
        const T: &str = "truth.parquet";
        const E: &str = "edges.parquet";
        for (k, (d, truth)) in s.obs.detections.iter().zip(&s.truth.detections).enumerate() {
            self.held += 1;
            for f in [N, T] {
                self.c(f, "run", run);
                self.c(f, "instance", instance);
                self.c(f, "side", side);
                self.c(f, "node", k as u64);
            }
            self.n(N, "x_m", d.position_m.x);
            self.n(N, "y_m", d.position_m.y);
            self.n(N, "cov_xx_m2", d.cov_m2[(0, 0)]);
            self.n(N, "cov_xy_m2", d.cov_m2[(0, 1)]);
            self.n(N, "cov_yy_m2", d.cov_m2[(1, 1)]);
            let a = &d.appearance;
            self.t(N, "class", a.class.as_str());
            for (name, v) in ["colour_r", "colour_g", "colour_b"]
                .iter()
                .zip(a.colour_rgb)
            {
                self.n(N, name, v);
            }
            self.n(N, "length_m", a.length_m);
            self.n(N, "width_m", a.width_m);
            self.n(N, "height_m", a.height_m);
            self.flags
                .entry((N, "sender"))
                .or_default()
                .push(truth.sender);
            self.t(T, "object_id", truth.object_id.as_deref().unwrap_or(""));
            let p = truth.position_m;
            self.n(T, "true_x_m", p.map_or(f64::NAN, |p| p.x));
            self.n(T, "true_y_m", p.map_or(f64::NAN, |p| p.y));
            self.n(T, "visible_fraction", truth.visible_fraction);
        }
        for e in &s.view.graph.edges {
            self.c(E, "run", run);
            self.c(E, "instance", instance);
            self.c(E, "side", side);
            self.c(E, "source", e.a.min(e.b) as u64);
            self.c(E, "target", e.a.max(e.b) as u64);
            self.n(E, "length_m", e.length_m);
        }
    }

    /// Writes every buffered row as row groups.
    fn write(&mut self, out: &mut TablesFolder) -> Result<(), OutputError> {
        for (file, _) in COLUMNS {
            let t = self.take(file);
            out.write(file, &t)?;
        }
        self.held = 0;
        Ok(())
    }
}

/// A matches file's rows as each scored run's [`ExternalMatches`], keyed
/// by run index (every run of `split` has an entry, empty when the file
/// names none of its instances). Refused, with the reason in one line,
/// when a row names a run that is not one of `split`, a level that is not
/// configured, or a node already matched in its instance and level, or
/// carries a probability outside [0, 1] or an uncertainty that is not a
/// finite number of bits; or when no row names a run of `split`.
pub fn external_matches(
    rows: &[MatchRow],
    runs: &[ExportRun],
    split: Split,
    levels: &[PoseNoiseLabel],
) -> Result<BTreeMap<usize, ExternalMatches>, String> {
    let mut out: BTreeMap<usize, ExternalMatches> = runs
        .iter()
        .filter(|r| r.split == split)
        .map(|r| (r.index, ExternalMatches::default()))
        .collect();
    let mut used: BTreeSet<(usize, usize, PoseNoiseLabel, u8, usize)> = BTreeSet::new();
    for (k, row) in rows.iter().enumerate() {
        let line = k + 1;
        let run = usize::try_from(row.run).unwrap_or(usize::MAX);
        let Some(matches) = out.get_mut(&run) else {
            return Err(match runs.get(run) {
                Some(r) => format!(
                    "row {line} names run {run}, a {} run; score the {} runs only (--split)",
                    r.split.as_str(),
                    split.as_str()
                ),
                None => format!(
                    "row {line} names run {run}, but this configuration has {} runs",
                    runs.len()
                ),
            });
        };
        let at: Vec<PoseNoiseLabel> = match &row.pose_noise {
            None => levels.to_vec(),
            Some(label) => match levels.iter().find(|l| l.as_str() == label) {
                Some(&l) => vec![l],
                None => {
                    let known: Vec<&str> = levels.iter().map(|l| l.as_str()).collect();
                    return Err(format!(
                        "row {line} names pose-noise level '{label}', not one of this configuration's ({})",
                        known.join(", ")
                    ));
                }
            },
        };
        let c = correspondence(row).map_err(|why| format!("row {line}: {why}"))?;
        let instance = usize::try_from(row.instance).unwrap_or(usize::MAX);
        for level in at {
            for (side, node) in [(0, c.a), (1, c.b)] {
                if !used.insert((run, instance, level, side, node)) {
                    return Err(format!(
                        "row {line} matches node {node} of the {} vehicle of run {run}, instance {instance} at level {} a second time",
                        ["first", "second"][usize::from(side)],
                        level.as_str()
                    ));
                }
            }
            matches
                .by_instance
                .entry((instance, level))
                .or_default()
                .push(c);
        }
    }
    if rows.is_empty() {
        return Err(format!("it names no {} run", split.as_str()));
    }
    for m in out.values_mut() {
        for list in m.by_instance.values_mut() {
            list.sort_by_key(|c| c.a);
        }
    }
    Ok(out)
}

/// A row's correspondence, its probability 1 and its uncertainty the
/// binary entropy of its probability unless it says otherwise.
fn correspondence(row: &MatchRow) -> Result<Correspondence, String> {
    let probability = row.probability.unwrap_or(1.0);
    if !(0.0..=1.0).contains(&probability) {
        return Err(format!("probability {probability} is not in [0, 1]"));
    }
    let uncertainty = row
        .uncertainty
        .unwrap_or_else(|| binary_entropy_bits(probability));
    if !(0.0..=1.0).contains(&uncertainty) {
        return Err(format!(
            "uncertainty {uncertainty} is not in [0, 1] (binary entropy in bits)"
        ));
    }
    let node = |v: u64| usize::try_from(v).map_err(|_| format!("node {v} is out of range"));
    Ok(Correspondence {
        a: node(row.a)?,
        b: node(row.b)?,
        probability,
        uncertainty,
    })
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn row(run: usize, a: u64, b: u64, level: Option<&str>) -> MatchRow {
        MatchRow {
            run: run as u64,
            instance: 3,
            pose_noise: level.map(str::to_owned),
            a,
            b,
            probability: None,
            uncertainty: None,
        }
    }

    /// Runs are numbered train, validation, test; a row without a level
    /// holds at every level, as a certain match; a node may be matched
    /// once per level.
    #[test]
    fn runs_are_numbered_by_split_and_rows_hold_per_level() {
        let s = Settings::from_toml(
            "[eval]\ntraffic_seeds = [1, 2]\n",
            Path::new("/tmp/somewhere/user.toml"),
        )
        .unwrap();
        let all = runs(&s).unwrap();
        assert!(all.iter().enumerate().all(|(k, r)| r.index == k));
        let splits: Vec<Split> = all.iter().map(|r| r.split).collect();
        assert!(splits.is_sorted() && splits.contains(&Split::Validation));
        let test: Vec<&ExportRun> = all.iter().filter(|r| r.split == Split::Test).collect();
        assert_eq!(test.iter().map(|r| r.seed).collect::<Vec<_>>(), [1, 2]);
        let t = test[0].index;
        let levels = [PoseNoiseLabel::None, PoseNoiseLabel::Gps];
        let m = external_matches(&[row(t, 1, 2, None)], &all, Split::Test, &levels).unwrap();
        assert_eq!(m.len(), 2);
        let at_gps = &m[&t].by_instance[&(3, PoseNoiseLabel::Gps)];
        assert_eq!((at_gps[0].probability, at_gps[0].uncertainty), (1.0, 0.0));
        assert_eq!(m[&t].by_instance.len(), 2);
        let fine = [row(t, 1, 2, Some("gps")), row(t, 1, 2, Some("none"))];
        assert!(external_matches(&fine, &all, Split::Test, &levels).is_ok());
        let twice = [row(t, 1, 2, Some("gps")), row(t, 0, 2, None)];
        let e = external_matches(&twice, &all, Split::Test, &levels).unwrap_err();
        assert!(e.contains("node 2 of the second vehicle"), "{e}");
        let validation = all.iter().find(|r| r.split == Split::Validation).unwrap();
        let e = external_matches(
            &[row(validation.index, 0, 0, None)],
            &all,
            Split::Test,
            &levels,
        )
        .unwrap_err();
        assert!(e.contains("a validation run"), "{e}");
    }
}
