//! Datasets from elsewhere, tried as a hostile user would: values that
//! are not numbers, unknown classes, wrong counts and dangling references
//! in a dataset's files, refused by its reader; runs without instances
//! said and not averaged; and the documented recipe for DMGM's pairs, run.
//! Each test is named after the defect it keeps fixed and goes through
//! the real binary.

use std::path::{Path, PathBuf};

use polars::prelude::*;

use crate::dataset::{convert, convert_split, rewrite, write_pairs};
use crate::util::*;

/// A copy of `dir` at `to`.
fn copy_dir(dir: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for f in std::fs::read_dir(dir).unwrap() {
        let f = f.unwrap().path();
        if f.is_dir() {
            copy_dir(&f, &to.join(f.file_name().unwrap()));
        } else {
            std::fs::copy(&f, to.join(f.file_name().unwrap())).unwrap();
        }
    }
}

/// The fixture's three pairs converted into `ds` (validation pair 10,
/// test pairs 11 and 12), and a copy of it for each of `n` edits.
fn converted(fx: &Fixture) -> PathBuf {
    write_pairs(&fx.path("src"));
    assert_ok(&convert(fx, "ds"));
    fx.path("ds")
}

/// `column` of `file` in a copy of `ds`, row `row` set to `value`.
fn with_value(
    fx: &Fixture,
    ds: &Path,
    name: &str,
    file: &str,
    column: &str,
    value: f64,
) -> PathBuf {
    let to = fx.path(name);
    copy_dir(ds, &to);
    rewrite(&to.join(file), |mut df| {
        let mut v: Vec<f64> = f64s(&df, column);
        v[0] = value;
        df.with_column(Column::new(column.into(), v)).unwrap();
        df
    });
    to
}

#[test]
fn non_finite_values_in_a_dataset_are_refused_by_its_reader() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    let cases = [
        (
            "nodes.parquet",
            "world_x_m",
            f64::NAN,
            "row 1, column 'world_x_m': NaN is not a number coid can use",
        ),
        (
            "nodes.parquet",
            "x_m",
            f64::INFINITY,
            "row 1, column 'x_m': inf is not a number coid can use",
        ),
        (
            "nodes.parquet",
            "x_m",
            1e300,
            "row 1, column 'x_m': 1e300 is farther than",
        ),
        (
            "instances.parquet",
            "position_sigma_m",
            f64::NAN,
            "row 1, column 'position_sigma_m': NaN is not a finite number >= 0",
        ),
        (
            "instances.parquet",
            "position_sigma_m",
            -1.0,
            "row 1, column 'position_sigma_m': -1 is not a finite number >= 0",
        ),
    ];
    for (k, (file, column, value, why)) in cases.into_iter().enumerate() {
        let d = with_value(&fx, &ds, &format!("bad{k}"), file, column, value);
        let o = fx.coid(&["dataset", d.to_str().unwrap()]);
        assert_refused(&o, &format!("{file}: {why}"));
    }
}

#[test]
fn unknown_classes_and_nan_appearance_in_a_dataset_are_refused_by_its_reader() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    // A class coid does not know.
    let d = fx.path("spaceship");
    copy_dir(&ds, &d);
    rewrite(&d.join("nodes.parquet"), |mut df| {
        let mut v = strs(&df, "class");
        v[0] = "spaceship".into();
        df.with_column(Column::new("class".into(), v)).unwrap();
        df
    });
    let o = fx.coid(&["dataset", d.to_str().unwrap()]);
    assert_refused(
        &o,
        "nodes.parquet: row 1, column 'class': 'spaceship' is not a class",
    );
    // An appearance value that is not a number.
    let d = fx.path("appearance");
    copy_dir(&ds, &d);
    rewrite(&d.join("nodes.parquet"), |mut df| {
        let lists: Vec<Series> = (0..df.height())
            .map(|k| {
                let first = if k == 2 { f32::NAN } else { 0.5 };
                Series::new("".into(), vec![first, 0.5, 0.5, 0.5])
            })
            .collect();
        df.with_column(Column::new("appearance".into(), lists))
            .unwrap();
        df
    });
    let o = fx.coid(&["dataset", d.to_str().unwrap()]);
    assert_refused(
        &o,
        "nodes.parquet: row 3, column 'appearance': NaN at position 0",
    );
    // Every --dataset reader reads through the same check.
    let d = with_value(&fx, &ds, "eval", "nodes.parquet", "world_x_m", f64::NAN);
    let cfg = fx.write(
        "gps.toml",
        "[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n",
    );
    let o = fx.coid(&[
        "eval",
        "-q",
        "-c",
        cfg.to_str().unwrap(),
        "--dataset",
        d.to_str().unwrap(),
    ]);
    assert_refused(&o, "nodes.parquet: row 1, column 'world_x_m': NaN");
}

#[test]
fn the_pose_refusal_names_the_second_vehicles_columns() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    // The first vehicle's pose given, no world positions for anyone.
    rewrite(&ds.join("instances.parquet"), |mut df| {
        let n = df.height();
        for c in ["first_x_m", "first_y_m", "first_heading_rad"] {
            df.with_column(Column::new(c.into(), vec![0.0; n])).unwrap();
        }
        df
    });
    rewrite(&ds.join("nodes.parquet"), |df| {
        df.drop("world_x_m").unwrap().drop("world_y_m").unwrap()
    });
    let o = fx.coid(&["dataset", ds.to_str().unwrap()]);
    assert_refused(
        &o,
        "the second vehicle has no reported pose (second_x_m, ...)",
    );
}

#[test]
fn a_wrong_instance_count_in_runs_parquet_is_refused() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    rewrite(&ds.join("runs.parquet"), |mut df| {
        df.with_column(Column::new("n_instances".into(), vec![1u64, 5]))
            .unwrap();
        df
    });
    let o = fx.coid(&["dataset", ds.to_str().unwrap()]);
    assert_refused(
        &o,
        "runs.parquet: row 2, column 'n_instances': 5, but instances.parquet holds 2 instances of run 1",
    );
}

#[test]
fn runs_without_instances_are_said_and_not_averaged() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    rewrite(&ds.join("runs.parquet"), |df| {
        let mut empty = df.slice(1, 1);
        empty
            .with_column(Column::new("run".into(), vec![2u64]))
            .unwrap();
        empty
            .with_column(Column::new("n_instances".into(), vec![0u64]))
            .unwrap();
        df.vstack(&empty).unwrap()
    });
    let o = fx.coid(&["dataset", ds.to_str().unwrap()]);
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("test: 2 runs, 2 instances"), "{said}");
    assert!(said.contains("runs without instances: 1 (tables average over the runs that have some): run 2 (test, dmgm/r1)"), "{said}");
    let cfg = fx.write(
        "gps.toml",
        "[matching]\nmethods = [\"mogm\", \"gps-hungarian\", \"oracle\"]\n",
    );
    let o = fx.coid(&[
        "eval",
        "-q",
        "-c",
        cfg.to_str().unwrap(),
        "--dataset",
        ds.to_str().unwrap(),
        "-o",
        "ev",
    ]);
    assert_ok(&o);
    for table in ["ev/table1.csv", "ev/table1b.csv"] {
        let t = read_csv(&fx.path(table));
        let n: Vec<i64> = t
            .column("n_runs")
            .unwrap()
            .i64()
            .unwrap()
            .into_no_null_iter()
            .collect();
        assert!(n.iter().all(|&n| n == 1), "{table}: {n:?}");
    }
}

#[test]
fn eval_on_a_dataset_without_test_runs_is_refused() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    assert_ok(&convert_split(&fx, "ds", &["validation=10..12"]));
    let cfg = fx.write(
        "gps.toml",
        "[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n",
    );
    let ds = fx.path("ds");
    let o = fx.coid(&[
        "eval",
        "-q",
        "-c",
        cfg.to_str().unwrap(),
        "--dataset",
        ds.to_str().unwrap(),
    ]);
    assert_refused(
        &o,
        "it has no test runs, which this command needs (its runs are validation;",
    );
}

#[test]
fn a_match_of_a_node_that_does_not_exist_is_refused_as_such() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    let mut df = df! {
        "run" => [1u64, 1],
        "instance" => [0u64, 0],
        "a" => [0u64, 1],
        "b" => [999u64, 999],
    }
    .unwrap();
    let file = fx.path("m.parquet");
    ParquetWriter::new(std::fs::File::create(&file).unwrap())
        .finish(&mut df)
        .unwrap();
    let cfg = fx.write(
        "gps.toml",
        "[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n",
    );
    let o = fx.coid(&[
        "score",
        "-q",
        "-c",
        cfg.to_str().unwrap(),
        "--dataset",
        ds.to_str().unwrap(),
        "--matches",
        file.to_str().unwrap(),
    ]);
    // (after the dataset's warning of what it lacks)
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    let last = e.trim_end().lines().last().unwrap_or_default();
    assert!(
        last.starts_with("error: ")
            && last
                .contains("a match names node 999 of the second vehicle, which has no such node"),
        "{e}"
    );
}

#[test]
fn a_true_pair_of_a_node_without_a_truth_row_says_so() {
    let fx = Fixture::new();
    let ds = converted(&fx);
    rewrite(&ds.join("truth.parquet"), |df| df.slice(1, df.height() - 1));
    let o = fx.coid(&["dataset", ds.to_str().unwrap()]);
    assert_refused(
        &o,
        "(no object: a false positive, or a node without a truth row)",
    );
}

/// The recipe of docs/data-from-elsewhere.md for DMGM's pairs, setup A,
/// on the fixture's pairs in DMGM's layout: a copy of the shipped models
/// is a models folder coid adds its choices to, and the evaluation runs.
#[test]
fn the_documented_recipe_for_data_from_elsewhere_runs() {
    let fx = Fixture::new();
    write_consistent_pairs_here(&fx);
    assert_ok(&convert_split(
        &fx,
        "dmgm-coid",
        &["validation=10..11", "test=12..12"],
    ));
    copy_dir(&repo().join("models"), &fx.path("dmgm-models"));
    let cfg = fx.write(
        "dmgm.toml",
        "[matching]\nmethods = [\"coid\", \"coid-paper-rule\", \"mogm\", \"rgm\", \"spectral\", \
         \"rrwm\", \"ours\", \"gps-hungarian\", \"gps-app-hungarian\", \"oracle\"]\n\
         models_dir = \"dmgm-models\"\n[eval]\ntraining_seeds = [7]\n",
    );
    let (c, d) = (cfg.to_str().unwrap(), "dmgm-coid");
    let train = |methods: &str| {
        fx.coid(&[
            "train",
            "-q",
            "-c",
            c,
            "--dataset",
            d,
            "--validate-only",
            "--methods",
            methods,
            "--out",
            "dmgm-models",
        ])
    };
    assert_ok(&train(
        "mogm,rgm,spectral,rrwm,gps-hungarian,gps-app-hungarian",
    ));
    assert_ok(&train("coid,ours"));
    assert_ok(&fx.coid(&["eval", "-q", "-c", c, "--dataset", d]));
    assert!(fx.path("results/dmgm-coid-eval/table1.csv").is_file());
}

fn write_consistent_pairs_here(fx: &Fixture) {
    crate::dataset::write_consistent_pairs(&fx.path("src"));
}

#[test]
fn reid_flags_and_keys_that_do_nothing_are_refused_naming_what_the_user_gave() {
    let fx = Fixture::new();
    let cfg = fx.config("w.toml", 20.0, "[appearance]\nwidth = 128\n");
    let o = fx.coid(&["run", "-q", "-c", cfg.to_str().unwrap()]);
    assert_refused(&o, "appearance.width");
    assert!(
        stderr(&o).contains("set [appearance] descriptor = \"reid\" too"),
        "{}",
        stderr(&o)
    );
    let o = fx.coid(&["train", "-q", "--reid-rank1", "1.0", "--validate-only"]);
    assert_refused(&o, "--reid-rank1 must be a rate in (0, 1), got 1");
    let o = fx.coid(&["train", "-q", "--reid-rank1", "0.5", "--validate-only"]);
    assert_refused(
        &o,
        "the default configuration sets [appearance] descriptor = \"none\"",
    );
    let reid = repo().join("configs/reid.toml");
    let o = fx.coid(&[
        "eval",
        "-q",
        "-c",
        reid.to_str().unwrap(),
        "--reid-sweep",
        "0.2,0.2",
    ]);
    assert_refused(&o, "--reid-sweep names the point 0.20 twice");
}
