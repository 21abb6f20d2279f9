//! `coid convert pyg` and `coid dataset`: PyTorch Geometric pairs written
//! by the test in DMGM's layout become a dataset coid reads back; a pickle
//! that would run code, a missing column and a node matched twice are
//! refused with their reasons.

use std::path::Path;

use polars::prelude::*;

use crate::pt_writer::{PtField, PtTensor, pyg_data};
use crate::util::*;

/// One view: objects `ids` at camera-frame (x right, z forward) `xz`,
/// seen from a vehicle at world (`at`, heading `h` rad, CARLA's
/// left-handed frame), with 4-value appearance vectors.
pub(crate) fn view(name: &str, ids: &[u32], xz: &[(f64, f64)], at: (f64, f64), h: f64) -> Vec<u8> {
    let n = ids.len();
    let pos: Vec<f64> = xz.iter().flat_map(|&(x, z)| [x, 1.5, z]).collect();
    // Camera (x right, z forward) -> CARLA (forward, right) -> world.
    let world: Vec<f64> = xz
        .iter()
        .flat_map(|&(x, z)| {
            let (f, r) = (z, x);
            [
                at.0 + f * h.cos() - r * h.sin(),
                at.1 + f * h.sin() + r * h.cos(),
                0.5,
            ]
        })
        .collect();
    // Each object's own appearance: its id's bits and a constant.
    let x: Vec<f64> = ids
        .iter()
        .flat_map(|&i| {
            [
                f64::from(i & 1),
                f64::from((i >> 1) & 1),
                f64::from((i >> 2) & 1),
                0.5,
            ]
        })
        .collect();
    let y: Vec<f64> = ids.iter().map(|&i| f64::from(i)).collect();
    pyg_data(&[
        (
            "x",
            PtField::Tensor(PtTensor::float(x, &[n, 4]).transposed()),
        ),
        ("y", PtField::Tensor(PtTensor::float(y, &[n]))),
        ("pos", PtField::Tensor(PtTensor::float(pos, &[n, 3]))),
        ("name", PtField::Text(name.to_owned())),
        (
            "pos_world",
            PtField::Tensor(PtTensor::float(world, &[n, 3])),
        ),
        ("label", PtField::Tensor(PtTensor::int(vec![2.0; n], &[n]))),
    ])
}

/// Three pairs of one recording (frames 5, 6, 7) in DMGM's layout under
/// `dir`: `proc_s/<k>/data.pt`, `proc_t/<k>/data.pt`, k = 10, 11, 12.
pub(crate) fn write_pairs(dir: &Path) {
    for (j, k) in [10u32, 11, 12].into_iter().enumerate() {
        let name = format!("data/proc_s/{k}/r1_{:04}", 5 + j);
        let s = view(
            &name,
            &[101, 102, 103, 104],
            &[(-3.0, 20.0), (2.0, 25.0), (0.5, 12.0), (6.0, 30.0)],
            (0.0, 0.0),
            0.3,
        );
        let t = view(
            &name,
            &[103, 101, 105],
            &[(1.0, 15.0), (-4.0, 22.0), (3.0, 9.0)],
            (5.0, -8.0),
            1.2,
        );
        for (v, bytes) in [("proc_s", s), ("proc_t", t)] {
            let d = dir.join(v).join(k.to_string());
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join("data.pt"), bytes).unwrap();
        }
    }
}

/// Like [`write_pairs`], but the two views see one world: objects 101-105
/// at fixed CARLA-frame places, each view's camera coordinates computed
/// from its vehicle's pose (pair k: both vehicles moved by k metres).
pub(crate) fn write_consistent_pairs(dir: &Path) {
    let world = [
        (101, (18.0, 4.0)),
        (102, (25.0, -6.0)),
        (103, (12.0, 9.0)),
        (104, (30.0, 2.0)),
        (105, (20.0, 15.0)),
    ];
    let seen = |at: (f64, f64), h: f64, ids: &[u32]| -> Vec<(f64, f64)> {
        ids.iter()
            .map(|id| {
                let (_, (wx, wy)) = world.iter().find(|(i, _)| i == id).unwrap();
                let (dx, dy) = (wx - at.0, wy - at.1);
                let f = dx * h.cos() + dy * h.sin();
                let r = -dx * h.sin() + dy * h.cos();
                (r, f)
            })
            .collect()
    };
    for (j, k) in [10u32, 11, 12].into_iter().enumerate() {
        let name = format!("data/proc_s/{k}/r1_{:04}", 5 + j);
        let shift = f64::from(k - 10);
        let (a, b) = ((shift - 2.0, -1.0), (shift + 1.0, 20.0));
        let ids_s = [101, 102, 103, 104];
        let ids_t = [103, 105, 101, 104];
        let s = view(&name, &ids_s, &seen(a, 0.1, &ids_s), a, 0.1);
        let t = view(&name, &ids_t, &seen(b, -0.6, &ids_t), b, -0.6);
        for (v, bytes) in [("proc_s", s), ("proc_t", t)] {
            let d = dir.join(v).join(k.to_string());
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join("data.pt"), bytes).unwrap();
        }
    }
}

pub(crate) fn convert(fx: &Fixture, out: &str) -> std::process::Output {
    convert_split(fx, out, &["validation=10..10", "test=11..12"])
}

/// `coid convert pyg` of the fixture's `src` into `out`, split as `splits`.
pub(crate) fn convert_split(fx: &Fixture, out: &str, splits: &[&str]) -> std::process::Output {
    let (src, dst) = (fx.path("src"), fx.path(out));
    let mut args = vec!["convert", "pyg", src.to_str().unwrap(), "-q", "-o"];
    args.extend([dst.to_str().unwrap(), "--splits"]);
    args.extend(splits);
    fx.coid(&args)
}

/// The converted pairs: runs by split, nodes in the body frame (x forward
/// = the camera's z, y left = minus its x), world positions right-handed,
/// appearance vectors read through their strides, true pairs from equal
/// ids; `coid dataset` reads it back and says so.
#[test]
fn converted_pyg_pairs_read_back_as_a_dataset() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    let runs = read_parquet(&fx.path("ds/runs.parquet"));
    let splits: Vec<String> = runs
        .column("split")
        .unwrap()
        .str()
        .unwrap()
        .iter()
        .map(|v| v.unwrap().to_owned())
        .collect();
    assert_eq!(splits, ["validation", "test"]);
    let nodes = read_parquet(&fx.path("ds/nodes.parquet"));
    let col = |n: &str| -> Vec<f64> {
        nodes
            .column(n)
            .unwrap()
            .f64()
            .unwrap()
            .into_no_null_iter()
            .collect()
    };
    let (x, y, wy) = (col("x_m"), col("y_m"), col("world_y_m"));
    assert_eq!((x[0], y[0]), (20.0, 3.0));
    let expected_wy = -(20.0 * 0.3f64.sin() + (-3.0) * 0.3f64.cos());
    assert!(
        (wy[0] - expected_wy).abs() < 1e-4,
        "{} vs {expected_wy}",
        wy[0]
    );
    assert!(
        nodes.column("cov_xx_m2").is_err(),
        "no covariance in the source, none written"
    );
    let pairs = read_parquet(&fx.path("ds/true_pairs.parquet"));
    let a: Vec<u64> = pairs
        .column("a")
        .unwrap()
        .u64()
        .unwrap()
        .into_no_null_iter()
        .take(2)
        .collect();
    let b: Vec<u64> = pairs
        .column("b")
        .unwrap()
        .u64()
        .unwrap()
        .into_no_null_iter()
        .take(2)
        .collect();
    assert_eq!((a, b), (vec![0, 2], vec![1, 0]));
    let o = fx.coid(&["dataset", fx.path("ds").to_str().unwrap()]);
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("validation: 1 run, 1 instances, 3.5 nodes per vehicle, 2.0 true pairs"),
        "{said}"
    );
    assert!(said.contains("test: 1 run, 2 instances"), "{said}");
    assert!(
        said.contains("appearance vectors: 4 values per node"),
        "{said}"
    );
}

/// A pair whose pickle would run code when torch loads it is refused by
/// the global it names; nothing is written, nothing is run.
#[test]
fn a_pt_file_whose_pickle_would_run_code_is_refused() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let mut p = crate::pt_writer::Pickle::default();
    p.op(0x80).op(2).global("os", "system");
    p.text(&format!("touch {}", fx.path("pwned").display()))
        .op(0x85)
        .op(b'R')
        .op(b'.');
    let evil = crate::pt_writer::archive(&p.0, &[]);
    std::fs::write(fx.path("src/proc_t/11/data.pt"), evil).unwrap();
    let o = convert(&fx, "ds");
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("names the global os.system"),
        "{}",
        stderr(&o)
    );
    assert!(!fx.path("pwned").exists());
    assert!(!fx.path("ds").exists());
}

pub(crate) fn rewrite(path: &Path, edit: impl FnOnce(DataFrame) -> DataFrame) {
    let mut df = edit(read_parquet(path));
    ParquetWriter::new(std::fs::File::create(path).unwrap())
        .finish(&mut df)
        .unwrap();
}

/// A dataset missing a required column, or whose true pairs match a node
/// twice, is refused with one line naming the file, row and column.
#[test]
fn a_dataset_with_a_missing_column_or_a_node_matched_twice_is_refused() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    std::fs::create_dir_all(fx.path("ds2")).unwrap();
    for f in std::fs::read_dir(fx.path("ds")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, fx.path("ds2").join(f.file_name().unwrap())).unwrap();
    }
    rewrite(&fx.path("ds/nodes.parquet"), |df| df.drop("x_m").unwrap());
    let o = fx.coid(&["dataset", fx.path("ds").to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("nodes.parquet: it has no column 'x_m'"),
        "{}",
        stderr(&o)
    );
    rewrite(&fx.path("ds2/true_pairs.parquet"), |df| {
        let first = df.slice(0, 1);
        let mut twice = first.clone();
        twice
            .with_column(Column::new("b".into(), vec![2u64]))
            .unwrap();
        first
            .vstack(&twice)
            .unwrap()
            .vstack(&df.slice(1, df.height() - 1))
            .unwrap()
    });
    let o = fx.coid(&["dataset", fx.path("ds2").to_str().unwrap()]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("true_pairs.parquet: row 2: node 0 of the first vehicle of run 0, instance 0 is matched a second time"), "{e}");
}

/// A dataset whose rows of one run are not one after another is refused
/// (coid reads a dataset run by run), naming the file and row.
#[test]
fn a_dataset_whose_run_rows_are_apart_is_refused() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    rewrite(&fx.path("ds/truth.parquet"), |df| {
        let n = df.height();
        // The last row (run 1) first: run 1 comes before and after run 0.
        df.slice(n as i64 - 1, 1)
            .vstack(&df.slice(0, n - 1))
            .unwrap()
    });
    let o = fx.coid(&["dataset", fx.path("ds").to_str().unwrap()]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("truth.parquet: row 9: the rows of run 1 are not together"),
        "{e}"
    );
}

/// The converted pairs evaluate as a dataset: every vehicle's pose is
/// fitted to its nodes' world positions (exact here, so GPS-Hungarian
/// finds every true pair and nothing else), the oracle finds the true
/// pairs, and the report names the dataset, not simulated runs.
#[test]
fn converted_pairs_evaluate_with_poses_fitted_to_their_world_positions() {
    let fx = Fixture::new();
    write_consistent_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    let config = fx.write(
        "c.toml",
        "[matching]\nmethods = [\"gps-hungarian\", \"gps-app-hungarian\", \"mogm\", \"oracle\"]\n",
    );
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&config)
        .args(["--dataset", fx.path("ds").to_str().unwrap()])
        .out("ev")
        .output();
    assert_ok(&o);
    assert!(
        stderr(&o).contains("on 2 test runs") || stderr(&o).contains("on 1 test run"),
        "{}",
        stderr(&o)
    );
    let table = fx.read_text("ev/table1b.csv");
    let row = |method: &str| -> Vec<String> {
        table
            .lines()
            .find(|l| l.starts_with(&format!("{method},gps,")))
            .unwrap_or_else(|| panic!("{method} in {table}"))
            .split(',')
            .map(str::to_owned)
            .collect()
    };
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    for method in ["gps-hungarian", "oracle"] {
        let r = row(method);
        for metric in ["precision", "recall", "f1"] {
            let v: f64 = r[col(metric)].parse().unwrap();
            assert!((v - 1.0).abs() < 1e-9, "{method} {metric} {v}");
        }
    }
    let summary = fx.read_text("ev/summary.md");
    assert!(
        summary.contains("the test runs of the dataset"),
        "{summary}"
    );
    // The appearance vectors tell the validation run's objects apart: a
    // positive slope, fitted there, reported.
    let slope: f64 = summary
        .split("likelihood ratio exp(")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .unwrap_or_else(|| panic!("{summary}"))
        .parse()
        .unwrap();
    assert!(slope > 1.0, "{slope}");
    // Regression: GPS+appearance Hungarian's probabilities stay
    // probabilities with appearance vectors (their Brier score was 9.6).
    let calibration = fx.read_text("ev/calibration.csv");
    let header: Vec<&str> = calibration.lines().next().unwrap().split(',').collect();
    let brier = header.iter().position(|c| *c == "brier").unwrap();
    let row: Vec<&str> = calibration
        .lines()
        .find(|l| l.starts_with("gps-app-hungarian,"))
        .unwrap_or_else(|| panic!("{calibration}"))
        .split(',')
        .collect();
    let b: f64 = row[brier].parse().unwrap();
    assert!((0.0..=1.0).contains(&b), "{calibration}");
    assert!(
        stderr(&o).contains("has no position covariances"),
        "{}",
        stderr(&o)
    );
}

/// A run exported and read back as a dataset evaluates exactly as the
/// run itself: every table of `coid eval` (deep methods with their
/// dropout samples, fusion errors, calibration) byte for byte.
#[test]
fn a_run_exported_and_read_back_evaluates_as_the_run_itself() {
    let (fx, config) = Fixture::with_config(
        60.0,
        "[matching]\nmethods = [\"gps-app-hungarian\", \"mogm\", \"ours\", \"oracle\"]\n\
         [eval]\ntraffic_seeds = [1, 2]\n",
    );
    let export = fx.cmd("export").quiet().config(&config);
    assert_ok(&export.args(["--splits", "test"]).out("ex").output());
    assert_ok(&fx.cmd("eval").quiet().config(&config).out("sim").output());
    let read = fx.cmd("eval").quiet().config(&config);
    let read = read.args(["--dataset", fx.path("ex").to_str().unwrap()]);
    assert_ok(&read.out("read").output());
    let mut compared = 0;
    for f in std::fs::read_dir(fx.path("sim")).unwrap() {
        let name = f.unwrap().file_name().to_string_lossy().into_owned();
        if name.ends_with(".csv") {
            assert_eq!(
                fx.read_text(&format!("read/{name}")),
                fx.read_text(&format!("sim/{name}")),
                "{name}"
            );
            compared += 1;
        }
    }
    assert!(compared >= 6, "{compared} tables");
    let instances = fx.read_text("sim/table1b.csv");
    assert!(instances.lines().count() > 3, "{instances}");
}

/// On a dataset with appearance vectors, validation chooses MOGM's
/// descriptor weight with its threshold, and the record names the
/// dataset.
#[test]
fn validation_chooses_the_descriptor_weight_of_the_learning_free_matchers() {
    let fx = Fixture::new();
    write_consistent_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    std::fs::create_dir_all(fx.path("models")).unwrap();
    let o = fx.coid(&[
        "train",
        "-q",
        "--dataset",
        fx.path("ds").to_str().unwrap(),
        "--validate-only",
        "--methods",
        "mogm",
        "--out",
        fx.path("models").to_str().unwrap(),
    ]);
    assert_ok(&o);
    assert!(stderr(&o).contains("descriptor weight"), "{}", stderr(&o));
    let record = fx.read_text("models/baselines.toml");
    assert!(record.contains("dataset = "), "{record}");
    let weight: f64 = record
        .lines()
        .find_map(|l| l.strip_prefix("descriptor_weight = "))
        .unwrap_or_else(|| panic!("{record}"))
        .parse()
        .unwrap();
    assert!([0.0, 0.25, 0.5, 0.75, 1.0].contains(&weight), "{weight}");
}

/// `coid score --dataset`: matches made from any dataset (here its own
/// true pairs) are scored on its test runs beside the built-in methods:
/// the true pairs score as the oracle.
#[test]
fn matches_made_from_a_converted_dataset_are_scored_on_it() {
    let fx = Fixture::new();
    write_consistent_pairs(&fx.path("src"));
    assert_ok(&convert(&fx, "ds"));
    let config = fx.write("c.toml", "[matching]\nmethods = [\"mogm\", \"oracle\"]\n");
    let ds = fx.path("ds");
    let matches = ds.join("true_pairs.parquet");
    let o = fx
        .cmd("score")
        .quiet()
        .config(&config)
        .args(["--dataset", ds.to_str().unwrap()])
        .args(["--matches", matches.to_str().unwrap()])
        .out("sc")
        .output();
    assert_ok(&o);
    let table = fx.read_text("sc/table1b.csv");
    let f1 = |method: &str| -> String {
        let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
        let col = header.iter().position(|c| *c == "f1").unwrap();
        table
            .lines()
            .find(|l| l.starts_with(&format!("{method},")))
            .unwrap_or_else(|| panic!("{method}: {table}"))
            .split(',')
            .nth(col)
            .unwrap()
            .to_owned()
    };
    assert_eq!(f1("external"), f1("oracle"), "{table}");
    assert!(
        fx.read_text("sc/summary.md")
            .contains("the test runs of the dataset"),
    );
}

/// Deep networks trained on a dataset with appearance vectors read them:
/// their first layer is as wide as class, colour and size (13) plus the
/// vector (4 here), the record says so, they evaluate on the dataset, and
/// data without such vectors (a simulated scene) is refused with the
/// reason instead of being read without them.
#[test]
fn deep_networks_trained_on_a_dataset_read_its_appearance_vectors() {
    let fx = Fixture::new();
    write_consistent_pairs(&fx.path("src"));
    let splits = ["train=10..10", "validation=11..11", "test=12..12"];
    assert_ok(&convert_split(&fx, "ds", &splits));
    let config = fx.write(
        "c.toml",
        &format!(
            "[train]\nepochs = 1\nno_match = \"halves\"\n[matching]\n\
             methods = [\"coid\", \"ours\", \"oracle\"]\nmodels_dir = {:?}\n",
            fx.path("models")
        ),
    );
    let ds = fx.path("ds");
    let train = fx.cmd("train").quiet().config(&config);
    let train = train.args(["--dataset", ds.to_str().unwrap(), "--methods", "coid,ours"]);
    assert_ok(&train.out("models").output());
    let coid = fx.read_text("models/coid.toml");
    assert!(coid.contains("appearance_width = 4"), "{coid}");
    let ours = fx.read_text("models/ours.toml");
    assert!(ours.contains("appearance_width = 4"), "{ours}");
    // The published network's NLL weighed "no match" as configured; the
    // validation runs chose each method's operating point with its rule.
    assert!(coid.contains("no_match = \"halves\""), "{coid}");
    assert!(!ours.contains("no_match"), "{ours}");
    for record in [&coid, &ours] {
        let validation = record.split("[validation]").nth(1).unwrap_or_default();
        assert!(validation.contains("min_probability = "), "{record}");
    }
    let eval = fx.cmd("eval").quiet().config(&config);
    let eval = eval.args(["--dataset", ds.to_str().unwrap()]);
    assert_ok(&eval.out("ev").output());
    assert!(fx.read_text("ev/table1.csv").contains("coid,"));
    assert!(fx.read_text("ev/summary.md").contains("at E[Y] >= "));
    let ap = fx.read_text("ev/precision_recall.csv");
    assert!(ap.lines().any(|l| l.starts_with("coid,")), "{ap}");
    let simulated = fx.method_config("sim.toml", "coid", "models");
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&simulated)
        .out("sim")
        .output();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("reads appearance vectors 4 wide; this data has none"),
        "{}",
        stderr(&o)
    );
}
