//! `coid run`: the results' columns and invariants, determinism over seeds
//! and threads, penetration, synchronized matching, killed and interrupted
//! runs, the golden default summary, an installed binary.

use crate::util::*;
use polars::prelude::DataFrame;
use std::path::PathBuf;
use std::process::Command;

/// The columns of a run's `summary.csv`, and its rows' invariants: 13
/// methods x 3 pose-noise levels x 2 fusion variants, enough
/// instances, rates in [0, 1], one object set (the same single-vehicle
/// error) for every method, a perfect oracle whose fusion beats the
/// single-vehicle error at every level with both variants.
fn check_summary(summary: &DataFrame) {
    let cols: Vec<String> = summary
        .get_column_names()
        .iter()
        .map(|c| c.to_string())
        .collect();
    for c in [
        "method",
        "pose_noise",
        "fusion",
        "n_instances",
        "precision",
        "recall",
        "f1",
        "de_single_m",
        "de_fused_m",
        "de_single_covis_m",
        "de_fused_covis_m",
        "de_fused_matched_m",
        "n_matched",
    ] {
        assert!(cols.iter().any(|x| x == c), "column {c} missing: {cols:?}");
    }
    // 16 methods x 3 pose-noise levels x 2 fusion variants.
    assert_eq!(summary.height(), 96);
    let (methods, noise) = (strs(summary, "method"), strs(summary, "pose_noise"));
    let fusion = strs(summary, "fusion");
    let (p, r) = (f64s(summary, "precision"), f64s(summary, "recall"));
    let (single, fused) = (f64s(summary, "de_single_m"), f64s(summary, "de_fused_m"));
    let n_inst = f64s(summary, "n_instances");
    assert!(
        n_inst.iter().all(|&n| n >= 5.0),
        "too few instances: {n_inst:?}"
    );
    for i in 0..summary.height() {
        assert!((0.0..=1.0).contains(&p[i]) && (0.0..=1.0).contains(&r[i]));
        assert_eq!(single[i], single[0], "{}: another object set", methods[i]);
        if methods[i] == "oracle" {
            assert_eq!((p[i], r[i]), (1.0, 1.0));
            assert!(
                fused[i] < single[i],
                "oracle/{}/{}: fused {} >= single {}",
                noise[i],
                fusion[i],
                fused[i],
                single[i]
            );
        }
    }
}

/// Every summary error can be recomputed from `objects.parquet`.
fn check_errors_recompute(summary: &DataFrame, objects: &DataFrame) {
    for c in [
        "truth_x",
        "truth_y",
        "single_x",
        "single_y",
        "fused_x",
        "fused_y",
        "ego_id",
        "object_id",
        "method",
        "pose_noise",
        "fusion",
    ] {
        assert!(objects.column(c).is_ok(), "objects.parquet lacks {c}");
    }
    let key = |df: &DataFrame| {
        let (m, n, f) = (
            strs(df, "method"),
            strs(df, "pose_noise"),
            strs(df, "fusion"),
        );
        (0..df.height())
            .map(|i| format!("{}/{}/{}", m[i], n[i], f[i]))
            .collect::<Vec<_>>()
    };
    let (keys, object_keys) = (key(summary), key(objects));
    let (single, fused) = (f64s(summary, "de_single_m"), f64s(summary, "de_fused_m"));
    let (tx, ty) = (f64s(objects, "truth_x"), f64s(objects, "truth_y"));
    let (sx, sy) = (f64s(objects, "single_x"), f64s(objects, "single_y"));
    let (fx, fy) = (f64s(objects, "fused_x"), f64s(objects, "fused_y"));
    for (i, k) in keys.iter().enumerate() {
        let rows: Vec<usize> = (0..objects.height())
            .filter(|&j| &object_keys[j] == k)
            .collect();
        assert!(!rows.is_empty(), "{k}: no object rows");
        let n = rows.len() as f64;
        let mean = |x: &[f64], y: &[f64]| {
            rows.iter()
                .map(|&j| (x[j] - tx[j]).hypot(y[j] - ty[j]))
                .sum::<f64>()
                / n
        };
        assert!((mean(&sx, &sy) - single[i]).abs() < 1e-5, "{k}: single");
        assert!((mean(&fx, &fy) - fused[i]).abs() < 1e-5, "{k}: fused");
    }
}

#[test]
fn short_real_run_writes_consistent_results() {
    let (fx, cfg) = Fixture::with_config(80.0, "");
    let out = fx.run(&cfg, "results/short");
    assert_ok(&out);
    let line = stderr(&out);
    assert!(line.contains("instances"), "{line}");
    // The deep networks' arithmetic, counted from their products' shapes.
    let gflop: f64 = line
        .split("; networks ")
        .nth(1)
        .and_then(|rest| rest.split(" GFLOP").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no network arithmetic in: {line}"));
    assert!(gflop > 0.0, "{line}");
    let dir = fx.path("results/short");
    for f in ["summary.csv", "objects.parquet", "summary.md"] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    let summary = read_csv(&dir.join("summary.csv"));
    check_summary(&summary);
    check_errors_recompute(&summary, &read_parquet(&dir.join("objects.parquet")));
    let leftovers: Vec<String> = dir
        .parent()
        .unwrap()
        .read_dir()
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn same_seeds_give_identical_bytes_other_seeds_do_not() {
    let fx = Fixture::new();
    let a = fx.config("a.toml", 75.0, "[seeds]\ntraffic = 3\nsensor = 5\n");
    let b = fx.config("b.toml", 75.0, "[seeds]\ntraffic = 3\nsensor = 6\n");
    assert_ok(&fx.run(&a, "one"));
    assert_ok(&fx.run(&a, "two"));
    assert_ok(&fx.run(&b, "other"));
    assert_eq!(fx.read("one/summary.csv"), fx.read("two/summary.csv"));
    assert_eq!(
        fx.read("one/objects.parquet"),
        fx.read("two/objects.parquet")
    );
    assert_ne!(fx.read("one/summary.csv"), fx.read("other/summary.csv"));
}

#[test]
fn penetration_rate_selects_many_connected_vehicles() {
    let (fx, cfg) = Fixture::with_config(
        70.0,
        "[connected]\npenetration = 0.3\n[matching]\nmethods = [\"oracle\"]\n[pose_noise]\nlevels = [\"gps\"]\n",
    );
    assert_ok(&fx.run(&cfg, "pen"));
    let objects = read_parquet(&fx.path("pen").join("objects.parquet"));
    let mut egos = strs(&objects, "ego_id");
    egos.sort();
    egos.dedup();
    assert!(
        egos.len() > 2,
        "expected more than two connected vehicles, got {egos:?}"
    );
}

/// With a penetration rate, steps hold many connected vehicles. Taken
/// pair by pair, GPS-Hungarian contradicts itself across three
/// vehicles; synchronised, it never does, and its objects are exactly
/// its pairs. The oracle is consistent either way.
#[test]
fn synchronized_matching_is_consistent_across_vehicles() {
    let fx = Fixture::new();
    let extra = |mode: &str| {
        format!(
            "[connected]\npenetration = 0.3\n[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\nmulti_vehicle = \"{mode}\"\n[pose_noise]\nlevels = [\"gps\"]\n"
        )
    };
    let mut runs = Vec::new();
    for mode in ["pairwise", "synchronized"] {
        let cfg = fx.config(&format!("{mode}.toml"), 70.0, &extra(mode));
        assert_ok(&fx.run(&cfg, mode));
        runs.push(read_csv(&fx.path(mode).join("summary.csv")));
    }
    let row = |df: &DataFrame, method: &str, col: &str| {
        let i = strs(df, "method").iter().position(|m| m == method).unwrap();
        f64s(df, col)[i]
    };
    let (pairwise, synced) = (&runs[0], &runs[1]);
    for df in [pairwise, synced] {
        assert!(row(df, "oracle", "triple_chains") > 100.0);
        assert_eq!(row(df, "oracle", "inconsistent_triple_share"), 0.0);
        assert_eq!(row(df, "oracle", "object_f1"), 1.0);
    }
    assert!(row(pairwise, "gps-hungarian", "inconsistent_triple_share") > 0.05);
    assert!(
        row(pairwise, "gps-hungarian", "object_precision")
            < row(pairwise, "gps-hungarian", "precision")
    );
    assert_eq!(
        row(synced, "gps-hungarian", "inconsistent_triple_share"),
        0.0
    );
    // The oracle's objects fused from every view beat the pairwise
    // fusion of the same (ego, object) set (aligned fusion, which
    // weighs each peer's pose uncertainty).
    let aligned = |df: &DataFrame, col: &str| {
        let (m, f) = (strs(df, "method"), strs(df, "fusion"));
        let i = (0..df.height())
            .position(|i| m[i] == "oracle" && f[i] == "aligned")
            .unwrap();
        f64s(df, col)[i]
    };
    let (pairwise_de, all_views_de) = (
        aligned(synced, "de_fused_pairwise_per_ego_m"),
        aligned(synced, "de_fused_all_views_m"),
    );
    assert!(
        all_views_de < pairwise_de,
        "all views {all_views_de} >= pairwise {pairwise_de}"
    );
    for (object, pair) in [
        ("object_precision", "precision"),
        ("object_recall", "recall"),
    ] {
        let (o, p) = (
            row(synced, "gps-hungarian", object),
            row(synced, "gps-hungarian", pair),
        );
        assert!((o - p).abs() < 1e-9, "{object} {o} != {pair} {p}");
    }
}

/// A run evaluates its steps on several threads while SUMO advances;
/// the bytes it writes do not depend on how many (every method,
/// several row groups of `objects.parquet`, both multi-vehicle modes).
#[test]
fn one_and_two_threads_give_identical_bytes() {
    let fx = Fixture::new();
    for mode in ["pairwise", "synchronized"] {
        let extra =
            format!("[connected]\npenetration = 0.3\n[matching]\nmulti_vehicle = \"{mode}\"\n");
        let cfg = fx.config(&format!("{mode}.toml"), 65.0, &extra);
        for threads in ["1", "2"] {
            let out = format!("{mode}-{threads}");
            let cmd = fx.cmd("run").quiet().args(["--threads", threads]);
            assert_ok(&cmd.config(&cfg).out(&out).output());
        }
        let objects = read_parquet(&fx.path(&format!("{mode}-1/objects.parquet")));
        assert!(
            objects.height() > 65_536,
            "{} rows: one row group",
            objects.height()
        );
        for f in ["summary.csv", "objects.parquet", "summary.md"] {
            let bytes = |t: &str| fx.read(&format!("{mode}-{t}/{f}"));
            assert!(
                bytes("1") == bytes("2"),
                "{mode}: {f} differs between 1 and 2 threads"
            );
        }
    }
}

/// A run killed while its rows stream to disk leaves no results
/// folder (only its hidden staging folder), and the same command then
/// completes.
#[test]
fn a_killed_run_leaves_no_half_written_folder() {
    use std::time::{Duration, Instant};
    let (fx, cfg) = Fixture::with_config(120.0, "[connected]\npenetration = 0.3\n");
    let run = || fx.cmd("run").quiet().config(&cfg).out("res/k");
    let mut child = run().command().spawn().unwrap();
    // Killed once its staging folder holds rows (a row group or more).
    let started = Instant::now();
    let staged_bytes = || -> u64 {
        std::fs::read_dir(fx.path("res"))
            .into_iter()
            .flatten()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(".k.tmp-"))
            .filter_map(|e| std::fs::metadata(e.path().join("objects.parquet")).ok())
            .map(|m| m.len())
            .sum()
    };
    wait_until(
        started + Duration::from_secs(120),
        "no rows streamed",
        || {
            assert!(
                child.try_wait().unwrap().is_none(),
                "the run ended before it was killed"
            );
            staged_bytes() >= 100_000
        },
    );
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!fx.path("res/k").exists(), "a half-written results folder");
    assert!(
        staged_bytes() > 0,
        "the killed run's staging folder is there"
    );
    assert_ok(&run().output());
    let objects = read_parquet(&fx.path("res/k/objects.parquet"));
    assert!(objects.height() > 0);
    // The next command in that folder removed the dead run's staging.
    assert_eq!(staged_bytes(), 0);
}

/// Ctrl-C ends a run with exit code 130 (not a Python
/// KeyboardInterrupt), leaving no results folder.
#[test]
fn ctrl_c_exits_130_and_leaves_no_results_folder() {
    use std::time::Duration;
    let (fx, cfg) = Fixture::with_config(120.0, "[connected]\npenetration = 0.3\n");
    let run = fx.cmd("run").quiet().config(&cfg).out("c");
    let mut child = run.command().spawn().unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run ended too soon"
    );
    send_signal(&child, "-INT");
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}");
    assert!(!fx.path("c").exists());
}

/// The default run's summary, byte for byte: `tests/golden/default-summary.csv`.
/// A change that moves the default results must say why (CHANGELOG.md)
/// and renew the file.
#[test]
fn the_ideal_mode_reproduces_the_results_from_before_v2x() {
    let fx = Fixture::new();
    assert_ok(&fx.cmd("run").quiet().out("r").output());
    let golden = "tests/golden/default-summary.csv";
    assert_same_csv(
        &fx.read_text("r/summary.csv"),
        &std::fs::read_to_string(repo().join(golden)).unwrap(),
        golden,
    );
}

/// A copy of the binary outside the checkout, run from an empty folder
/// without `--config`: the defaults are compiled in, the default
/// scenario and the shipped weights come out of the binary into its
/// data folder, and the results land in the working folder.
#[test]
fn an_installed_coid_runs_from_any_folder_without_a_config() {
    let fx = Fixture::new();
    let bin = fx.path("prefix/bin/coid");
    std::fs::create_dir_all(bin.parent().unwrap()).unwrap();
    std::fs::copy(BIN, &bin).unwrap();
    let work = fx.path("somewhere/else");
    std::fs::create_dir_all(&work).unwrap();
    // A bare environment: no Python on PATH but the system's (whose
    // standard library must not be taken for the linked one's).
    let out = Command::new(&bin)
        .args(["run", "--quiet"])
        .current_dir(&work)
        .env_clear()
        .env("PATH", "/usr/bin:/bin")
        .env("HOME", fx.path("home"))
        .env("COID_HOME", fx.path("home"))
        .env("COID_VENV", venv())
        .output()
        .unwrap();
    assert_ok(&out);
    let summary = read_csv(&work.join("results/default/summary.csv"));
    check_summary(&summary);
    let installed: Vec<PathBuf> = std::fs::read_dir(fx.path("home"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("install-")
        })
        .collect();
    assert_eq!(installed.len(), 1, "{installed:?}");
    for f in [
        "models/ours.bpk",
        "sumo_nets/intersection/intersection.sumocfg",
        "configs/default.toml",
    ] {
        assert!(installed[0].join(f).is_file(), "{f}");
    }
    // The same bytes as a run of the checkout's default config.
    let default = repo().join("configs/default.toml");
    assert_ok(&fx.cmd("run").quiet().config(&default).out("ref").output());
    assert_eq!(
        std::fs::read(work.join("results/default/summary.csv")).unwrap(),
        fx.read("ref/summary.csv")
    );
}

#[test]
fn help_lists_the_run_command() {
    let fx = Fixture::new();
    let out = fx.coid(&["--help"]);
    assert_ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("run") && text.contains("SUMO"), "{text}");
}
