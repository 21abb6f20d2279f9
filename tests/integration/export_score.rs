//! `coid export` and `coid score`: exported matches score as the built-in
//! method.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Output;

/// A fixture with a short config: the fast methods, two test runs.
fn small() -> (Fixture, PathBuf) {
    Fixture::with_config(
        60.0,
        "[matching]\nmethods = [\"gps-hungarian\", \"gps-app-hungarian\", \"oracle\"]\n\
         [eval]\ntraffic_seeds = [1, 2]\n",
    )
}

/// `coid export` of the test runs into `ex`, with GPS-Hungarian's matches.
fn export(fx: &Fixture, config: &Path) {
    let export = fx
        .cmd("export")
        .quiet()
        .config(config)
        .args(["--splits", "test"]);
    assert_ok(
        &export
            .args(["--with-matches", "gps-hungarian"])
            .out("ex")
            .output(),
    );
}

/// `coid score` of `matches` (made from the export `ex`).
fn score(fx: &Fixture, config: &Path, matches: &str, out: &str) -> Output {
    let score = fx
        .cmd("score")
        .quiet()
        .config(config)
        .args(["--matches", matches]);
    score.out(out).args(["--export", "ex"]).output()
}

/// The lines of a table for `method`, without the method.
/// The rows of `method` in a table, without the method and what it sees
/// (the `inputs` column, where the table has one).
fn rows(fx: &Fixture, dir: &str, file: &str, method: &str) -> Vec<String> {
    let text = fx.read_text(&format!("{dir}/{file}"));
    let inputs = text
        .lines()
        .next()
        .and_then(|h| h.split(',').position(|c| c == "inputs"));
    text.lines()
        .filter(|l| l.split(',').next() == Some(method))
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|&(k, _)| k != 0 && Some(k) != inputs)
                .map(|(_, v)| v)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

/// Export then score: GPS-Hungarian's exported matches score exactly
/// as GPS-Hungarian (P/R/F1, displacement errors with both fusion
/// variants, calibration, consistency, all-view fusion), and the
/// exported true pairs exactly as the oracle; the export says what it
/// holds.
#[test]
fn exported_matches_reproduce_the_built_in_rows() {
    let (fx, config) = small();
    export(&fx, &config);
    let runs = read_parquet(&fx.path("ex/runs.parquet"));
    assert_eq!(strs(&runs, "split"), vec!["test", "test"]);
    assert_eq!(f64s(&runs, "schema_version"), vec![5.0, 5.0]);
    let instances: f64 = f64s(&runs, "n_instances").iter().sum();
    assert!(instances > 0.0);
    let levels = read_parquet(&fx.path("ex/instances.parquet")).height() as f64;
    assert_eq!(levels, 3.0 * instances);
    let nodes = read_parquet(&fx.path("ex/nodes.parquet"));
    assert_eq!(
        nodes.height(),
        read_parquet(&fx.path("ex/truth.parquet")).height()
    );
    assert!(fx.read_text("ex/schema.md").contains("schema version 5"));
    // The export is a dataset coid reads back.
    let o = fx.coid(&["dataset", fx.path("ex").to_str().unwrap()]);
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains(&format!("test: 2 runs, {instances} instances")),
        "{said}"
    );
    assert_ok(&score(
        &fx,
        &config,
        "ex/matches-gps-hungarian.parquet",
        "s1",
    ));
    assert_ok(&score(&fx, &config, "ex/true_pairs.parquet", "s2"));
    for file in [
        "table1b.csv",
        "errors.csv",
        "calibration.csv",
        "precision_recall.csv",
        "pr_curve.csv",
        "consistency.csv",
        "views.csv",
    ] {
        let built_in = rows(&fx, "s1", file, "gps-hungarian");
        assert!(!built_in.is_empty(), "{file}");
        assert_eq!(rows(&fx, "s1", file, "external"), built_in, "{file}");
        assert_eq!(
            rows(&fx, "s2", file, "external"),
            rows(&fx, "s2", file, "oracle"),
            "{file}"
        );
    }
    // Another method's matches are not GPS-Hungarian's.
    assert_ne!(
        rows(&fx, "s1", "table1b.csv", "external"),
        rows(&fx, "s1", "table1b.csv", "gps-app-hungarian")
    );
}

/// A matches file that does not fit the exported instances is refused
/// with one line and a non-zero exit, and nothing is written.
#[test]
fn a_matches_file_that_does_not_fit_is_refused_in_one_line() {
    let (fx, config) = small();
    export(&fx, &config);
    let run = f64s(&read_parquet(&fx.path("ex/runs.parquet")), "run")[0] as u64;
    let cases = [
        (
            format!("run,instance,a,b\n{run},0,999,0\n"),
            "a match names node 999 of the first vehicle, which has no such node",
        ),
        (
            format!("run,instance,a,b\n{run},100000,0,0\n"),
            "matches name instance 100000",
        ),
        (
            "run,instance,a,b\n0,0,0,0\n".into(),
            "names no test run (its one row names a run of another split)",
        ),
        (
            "run,instance,a,b\n99999,0,0,0\n".into(),
            "this configuration has",
        ),
        (
            format!("run,instance,pose_noise,a,b\n{run},0,foo,0,0\n"),
            "pose-noise level 'foo'",
        ),
        (
            format!("run,instance,a,b\n{run},0,0,0\n{run},0,0,1\n"),
            "a second time",
        ),
        (
            format!("run,instance,a,b,probability\n{run},0,0,0,2\n"),
            "not in [0, 1]",
        ),
        (format!("run,instance,a\n{run},0,0\n"), "no column 'b'"),
        (format!("run,instance,a,b\n{run},0,-1,0\n"), "negative"),
        ("run,instance,a,b\n".into(), "names no test run"),
    ];
    for (k, (body, expect)) in cases.iter().enumerate() {
        let file = format!("bad{k}.csv");
        fx.write(&file, body);
        let o = score(&fx, &config, &file, "s");
        assert_refused_unwritten(&o, expect, &fx.path("s"));
    }
}

/// Schema 3: every exported node carries its box's heading and speed (a
/// sender's own node its own, heading 0 in its body frame); an export
/// written by an older coid (schema 2, without them) is refused with the
/// reason, not scored against instances it does not hold.
#[test]
fn r34_exports_carry_boxes_and_an_older_schema_is_refused() {
    let (fx, config) = small();
    export(&fx, &config);
    let nodes = read_parquet(&fx.path("ex/nodes.parquet"));
    let heading = f64s(&nodes, "heading_rad");
    let speed = f64s(&nodes, "speed_mps");
    assert!(heading.iter().all(|h| h.abs() <= std::f64::consts::PI));
    assert!(speed.iter().all(|s| *s >= 0.0 && s.is_finite()));
    assert!(speed.iter().any(|s| *s > 1.0), "someone moves");
    let sender = nodes.column("sender").unwrap().bool().unwrap().clone();
    for (k, is_sender) in sender.iter().enumerate() {
        if is_sender == Some(true) {
            assert_eq!(heading[k], 0.0);
        }
    }
    assert_ok(&score(
        &fx,
        &config,
        "ex/matches-gps-hungarian.parquet",
        "s1",
    ));
    // The same export as schema 2 wrote it.
    let path = fx.path("ex/runs.parquet");
    let mut runs = read_parquet(&path);
    let n = runs.height();
    runs.with_column(polars::prelude::Column::new(
        "schema_version".into(),
        vec![2u64; n],
    ))
    .unwrap();
    polars::prelude::ParquetWriter::new(std::fs::File::create(&path).unwrap())
        .finish(&mut runs)
        .unwrap();
    let o = score(&fx, &config, "ex/matches-gps-hungarian.parquet", "s2");
    assert_refused_unwritten(&o, "older coid (export schema 2", &fx.path("s2"));
}

/// `coid export --dataset`: a dataset's runs written again with a
/// built-in method's matches on them: the pairs the export made while
/// simulating, their probabilities to round-off (the dataset's
/// covariances are rebuilt from three numbers), the same true pairs; it
/// says which splits it holds.
#[test]
fn export_of_a_dataset_writes_the_built_in_matches_on_its_runs() {
    let (fx, config) = small();
    export(&fx, &config);
    let again = fx.cmd("export").quiet().config(&config);
    let again = again.args(["--dataset", fx.path("ex").to_str().unwrap()]);
    let o = again
        .args(["--with-matches", "gps-hungarian"])
        .out("ex2")
        .output();
    assert_ok(&o);
    assert!(stderr(&o).contains(") of test; wrote"), "{}", stderr(&o));
    let read = |dir: &str, file: &str| read_parquet(&fx.path(&format!("{dir}/{file}")));
    let (first, second) = (
        read("ex", "matches-gps-hungarian.parquet"),
        read("ex2", "matches-gps-hungarian.parquet"),
    );
    assert!(first.height() > 0);
    for column in ["run", "instance", "a", "b"] {
        assert_eq!(f64s(&first, column), f64s(&second, column), "{column}");
    }
    assert_eq!(strs(&first, "pose_noise"), strs(&second, "pose_noise"));
    for column in ["probability", "uncertainty"] {
        for (x, y) in f64s(&first, column).iter().zip(f64s(&second, column)) {
            assert!((x - y).abs() < 1e-12, "{column}: {x} vs {y}");
        }
    }
    let pairs = read("ex", "true_pairs.parquet");
    assert!(pairs.equals(&read("ex2", "true_pairs.parquet")));
}
