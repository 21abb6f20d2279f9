//! Integration tests: the real `coid` binary runs the real SUMO (libsumo in
//! process, through the bridge) on the shipped scenario, for short runs.
//! Every test works in its own temporary folder; each binary invocation is
//! its own process, so the libsumo singleton never sees two simulations.
//! One test (`likelihood::`) drives the library itself, SUMO included, in
//! this test process: the only one that may.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use polars::prelude::*;

const BIN: &str = env!("CARGO_BIN_EXE_coid");

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The `coid` binary in `dir`, with its data folder there too (each test
/// writes out the carried files for itself) and SUMO's environment from
/// `COID_VENV` or the checkout's `.venv` (never a new download).
fn coid_in(dir: &Path) -> Command {
    let mut c = Command::new(BIN);
    c.current_dir(dir).env("COID_HOME", dir.join(".coid-home"));
    if std::env::var_os("COID_VENV").is_none() {
        c.env("COID_VENV", repo().join(".venv"));
    }
    c
}

fn shipped_sumocfg() -> PathBuf {
    repo().join("sumo_nets/intersection/intersection.sumocfg")
}

/// A temporary folder with helpers to write configs and run the binary.
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn new() -> Self {
        Fixture {
            dir: tempfile::tempdir().expect("temp dir"),
        }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Writes a config: the shipped scenario, run for `end_s`, plus `extra`
    /// TOML (sections after `[scenario]`). Everything else comes from the
    /// defaults, the shipped weights included.
    fn config(&self, name: &str, end_s: f64, extra: &str) -> PathBuf {
        let body = format!(
            "[scenario]\nsumocfg = {:?}\njunction = \"C\"\nend_s = {end_s}\n{extra}",
            shipped_sumocfg().to_string_lossy()
        );
        self.write(name, &body)
    }

    fn write(&self, name: &str, body: &str) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, body).expect("write");
        p
    }

    fn coid(&self, args: &[&str]) -> Output {
        coid_in(self.dir.path())
            .args(args)
            .output()
            .expect("run coid")
    }

    fn run(&self, config: &Path, out: &str) -> Output {
        self.coid(&[
            "run",
            "--quiet",
            "--config",
            config.to_str().unwrap(),
            "--out",
            out,
        ])
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn assert_ok(o: &Output) {
    assert!(o.status.success(), "coid failed: {}", stderr(o));
}

/// Polls `done` every 10 ms until it holds; fails with `what` once
/// `deadline` has passed.
fn wait_until(deadline: std::time::Instant, what: &str, mut done: impl FnMut() -> bool) {
    while !done() {
        assert!(std::time::Instant::now() < deadline, "{what}");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

fn read_csv(path: &Path) -> DataFrame {
    CsvReadOptions::default()
        .with_has_header(true)
        .try_into_reader_with_file_path(Some(path.to_owned()))
        .expect("csv reader")
        .finish()
        .expect("read csv")
}

fn read_parquet(path: &Path) -> DataFrame {
    ParquetReader::new(File::open(path).expect("open parquet"))
        .finish()
        .expect("read parquet")
}

fn f64s(df: &DataFrame, col: &str) -> Vec<f64> {
    df.column(col)
        .unwrap()
        .cast(&DataType::Float64)
        .unwrap()
        .f64()
        .unwrap()
        .iter()
        .map(|v| v.unwrap_or(f64::NAN))
        .collect()
}

fn strs(df: &DataFrame, col: &str) -> Vec<String> {
    df.column(col)
        .unwrap()
        .str()
        .unwrap()
        .iter()
        .map(|v| v.unwrap_or("").to_owned())
        .collect()
}

mod run {
    use super::*;

    /// The columns of a run's `summary.csv`, and its rows' invariants: 11
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
        assert_eq!(summary.height(), 66);
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
        let fx = Fixture::new();
        let cfg = fx.config("short.toml", 80.0, "");
        let out = fx.run(&cfg, "results/short");
        assert_ok(&out);
        assert!(stderr(&out).contains("instances"), "{}", stderr(&out));
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
        let bytes = |d: &str, f: &str| std::fs::read(fx.path(d).join(f)).unwrap();
        assert_eq!(bytes("one", "summary.csv"), bytes("two", "summary.csv"));
        assert_eq!(
            bytes("one", "objects.parquet"),
            bytes("two", "objects.parquet")
        );
        assert_ne!(bytes("one", "summary.csv"), bytes("other", "summary.csv"));
    }

    #[test]
    fn penetration_rate_selects_many_connected_vehicles() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "pen.toml",
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
                let args = ["run", "-q", "--threads", threads, "--config"];
                let o = fx.coid(&[&args[..], &[cfg.to_str().unwrap(), "--out", &out]].concat());
                assert_ok(&o);
            }
            let objects = read_parquet(&fx.path(&format!("{mode}-1/objects.parquet")));
            assert!(
                objects.height() > 65_536,
                "{} rows: one row group",
                objects.height()
            );
            for f in ["summary.csv", "objects.parquet", "summary.md"] {
                let bytes = |t: &str| std::fs::read(fx.path(&format!("{mode}-{t}/{f}"))).unwrap();
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
        let fx = Fixture::new();
        let cfg = fx.config("k.toml", 120.0, "[connected]\npenetration = 0.3\n");
        let args = [
            "run",
            "-q",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            "res/k",
        ];
        let mut child = coid_in(fx.dir.path()).args(args).spawn().unwrap();
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
        assert_ok(&fx.coid(&args));
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
        let fx = Fixture::new();
        let cfg = fx.config("c.toml", 120.0, "[connected]\npenetration = 0.3\n");
        let mut child = coid_in(fx.dir.path())
            .args(["run", "-q", "--config", cfg.to_str().unwrap(), "--out", "c"])
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(2500));
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended too soon"
        );
        let pid = child.id().to_string();
        assert!(
            Command::new("kill")
                .args(["-INT", &pid])
                .status()
                .unwrap()
                .success()
        );
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(130), "{status:?}");
        assert!(!fx.path("c").exists());
    }

    /// `[v2x] mode = "ideal"`, the default, reproduces byte for byte the
    /// default run's summary as the binary from before `[v2x]` (commit
    /// 2752208) wrote it: `tests/golden/default-summary.csv`. A change
    /// that moves the default results must say why and renew the file.
    #[test]
    fn the_ideal_mode_reproduces_the_results_from_before_v2x() {
        let fx = Fixture::new();
        assert_ok(&fx.coid(&["run", "-q", "-o", "r"]));
        assert_eq!(
            std::fs::read_to_string(fx.path("r/summary.csv")).unwrap(),
            std::fs::read_to_string(repo().join("tests/golden/default-summary.csv")).unwrap()
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
        let venv =
            std::env::var_os("COID_VENV").map_or_else(|| repo().join(".venv"), PathBuf::from);
        // A bare environment: no Python on PATH but the system's (whose
        // standard library must not be taken for the linked one's).
        let out = Command::new(&bin)
            .args(["run", "--quiet"])
            .current_dir(&work)
            .env_clear()
            .env("PATH", "/usr/bin:/bin")
            .env("HOME", fx.path("home"))
            .env("COID_HOME", fx.path("home"))
            .env("COID_VENV", venv)
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
        let checkout = fx.coid(&[
            "run",
            "-q",
            "--config",
            repo().join("configs/default.toml").to_str().unwrap(),
            "--out",
            "ref",
        ]);
        assert_ok(&checkout);
        assert_eq!(
            std::fs::read(work.join("results/default/summary.csv")).unwrap(),
            std::fs::read(fx.path("ref/summary.csv")).unwrap()
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
}

mod protocol {
    use super::*;

    /// A user's own config in their own folder, holding only `[scenario]`
    /// and `[connected]` (docs/configuration.md's example), runs with the shipped
    /// weights and their validated lambdas.
    #[test]
    fn a_minimal_user_config_runs_with_the_shipped_models() {
        let fx = Fixture::new();
        std::fs::create_dir_all(fx.path("mine")).unwrap();
        let cfg = fx.write(
            "mine/study.toml",
            &format!(
                "[scenario]\nsumocfg = {:?}\njunction = \"C\"\nend_s = 80\n[connected]\nids = [\"cv0\", \"cv1\"]\n",
                shipped_sumocfg().to_string_lossy()
            ),
        );
        assert_ok(&fx.run(&cfg, "mine/out"));
        let summary = read_csv(&fx.path("mine/out/summary.csv"));
        let methods = strs(&summary, "method");
        for m in ["ours", "ours-noprior", "gps-app-hungarian", "oracle"] {
            assert!(methods.iter().any(|x| x == m), "{m} missing");
        }
    }

    /// With lambda 0 the thresholding methods keep no pair: their
    /// precision is undefined (not 1), recall and F1 are 0.
    #[test]
    fn a_method_that_identifies_nothing_has_undefined_precision() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "zero.toml",
            70.0,
            "[matching]\nmethods = [\"ours\", \"oracle\"]\nlambda = 0.0\n[pose_noise]\nlevels = [\"gps\"]\n",
        );
        assert_ok(&fx.run(&cfg, "zero"));
        let summary = read_csv(&fx.path("zero/summary.csv"));
        let (m, p, r) = (
            strs(&summary, "method"),
            f64s(&summary, "precision"),
            f64s(&summary, "recall"),
        );
        let (f1, matched) = (f64s(&summary, "f1"), f64s(&summary, "n_matched"));
        for i in 0..summary.height() {
            if m[i] == "ours" {
                assert!(p[i].is_nan(), "precision {}", p[i]);
                assert_eq!((r[i], f1[i], matched[i]), (0.0, 0.0, 0.0));
            } else {
                assert_eq!(p[i], 1.0);
            }
        }
        let md = std::fs::read_to_string(fx.path("zero/summary.md")).unwrap();
        assert!(
            md.contains("| ours | gps | paper |") && md.contains("n/a"),
            "{md}"
        );
    }
}

mod bad_input {
    use super::*;

    /// Runs `config` and checks: non-zero exit, one line on stderr that
    /// contains `expect`, no panic, and no output folder.
    fn fails_cleanly(fx: &Fixture, config: &Path, expect: &str) {
        let out = fx.run(config, "out");
        let err = stderr(&out);
        assert!(!out.status.success(), "expected failure for {expect}");
        assert!(!err.contains("panicked"), "panic: {err}");
        assert_eq!(err.trim().lines().count(), 1, "not one line: {err}");
        assert!(err.starts_with("error: "), "{err}");
        assert!(err.contains(expect), "expected {expect:?} in: {err}");
        assert!(!fx.path("out").exists(), "half-written results left behind");
    }

    #[test]
    fn missing_config_file() {
        let fx = Fixture::new();
        fails_cleanly(&fx, &fx.path("nope.toml"), "cannot read config file");
    }

    #[test]
    fn malformed_toml() {
        let fx = Fixture::new();
        let cfg = fx.write("bad.toml", "[scenario\nsumocfg = 3\n");
        fails_cleanly(&fx, &cfg, "bad.toml:1:");
    }

    #[test]
    fn unknown_key() {
        let fx = Fixture::new();
        let cfg = fx.config("k.toml", 60.0, "[sensor]\nrange_sigma = 1.0\n");
        fails_cleanly(&fx, &cfg, "unknown field `range_sigma`");
    }

    #[test]
    fn missing_scenario_file() {
        let fx = Fixture::new();
        let cfg = fx.write(
            "m.toml",
            "[scenario]\nsumocfg = \"missing.sumocfg\"\njunction = \"C\"\n",
        );
        fails_cleanly(&fx, &cfg, "no such file");
    }

    #[test]
    fn unknown_junction() {
        let fx = Fixture::new();
        let cfg = fx.write(
            "j.toml",
            &format!(
                "[scenario]\nsumocfg = {:?}\njunction = \"Z9\"\nend_s = 60\n[matching]\nmethods = [\"oracle\"]\n",
                shipped_sumocfg().to_string_lossy()
            ),
        );
        fails_cleanly(&fx, &cfg, "junction 'Z9' does not exist");
    }

    #[test]
    fn unknown_connected_vehicle() {
        let fx = Fixture::new();
        let cfg = fx.config("v.toml", 60.0, "[connected]\nids = [\"cv0\", \"ghost\"]\n");
        fails_cleanly(&fx, &cfg, "\"ghost\"");
    }

    /// A config whose SUMO cannot start (its net file does not exist).
    fn broken_sumo(fx: &Fixture) -> PathBuf {
        fx.write(
            "broken.sumocfg",
            "<configuration><input><net-file value=\"no-such.net.xml\"/></input></configuration>",
        );
        fx.write(
            "s.toml",
            "[scenario]\nsumocfg = \"broken.sumocfg\"\njunction = \"C\"\n[matching]\nmethods = [\"oracle\"]\n",
        )
    }

    #[test]
    fn sumo_fails_to_start() {
        let fx = Fixture::new();
        let cfg = broken_sumo(&fx);
        fails_cleanly(&fx, &cfg, "SUMO failed to start");
    }

    /// An output folder that cannot be made is refused before the
    /// simulation starts (this scenario's SUMO would fail to start).
    #[test]
    fn an_unwritable_out_is_refused_before_the_simulation() {
        let fx = Fixture::new();
        let cfg = broken_sumo(&fx);
        fx.write("a-file", "not a folder");
        let out = fx.run(&cfg, "a-file/out");
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("a-file") && !err.contains("SUMO"), "{err}");
    }

    #[test]
    fn sumo_fails_mid_run() {
        let fx = Fixture::new();
        // SUMO reads routes in one-second chunks, so the broken route of
        // vehicle b is only found once the simulation is under way.
        fx.write(
            "r.rou.xml",
            r#"<routes>
    <vType id="car" length="4.6"/>
    <vehicle id="a" type="car" depart="0"><route edges="W2C C2E"/></vehicle>
    <vehicle id="c" type="car" depart="10"><route edges="S2C C2N"/></vehicle>
    <vehicle id="d" type="car" depart="20"><route edges="S2C C2N"/></vehicle>
    <vehicle id="b" type="car" depart="30"><route edges="W2C nope"/></vehicle>
</routes>"#,
        );
        fx.write(
            "mid.sumocfg",
            &format!(
                "<configuration><input><net-file value={:?}/><route-files value=\"r.rou.xml\"/></input>\
                 <processing><route-steps value=\"1\"/></processing></configuration>",
                repo()
                    .join("sumo_nets/intersection/intersection.net.xml")
                    .to_string_lossy()
            ),
        );
        let cfg = fx.write(
            "mid.toml",
            "[scenario]\nsumocfg = \"mid.sumocfg\"\njunction = \"C\"\nend_s = 60\n[connected]\nids = [\"a\", \"c\"]\n[matching]\nmethods = [\"oracle\"]\n",
        );
        fails_cleanly(&fx, &cfg, "SUMO failed at t = ");
    }

    #[test]
    fn existing_results_are_kept_without_force() {
        let fx = Fixture::new();
        let cfg = fx.config("e.toml", 60.0, "");
        std::fs::create_dir_all(fx.path("out")).unwrap();
        std::fs::write(fx.path("out/summary.csv"), "precious").unwrap();
        let out = fx.run(&cfg, "out");
        assert!(!out.status.success());
        assert!(stderr(&out).contains("already exists"), "{}", stderr(&out));
        assert_eq!(
            std::fs::read_to_string(fx.path("out/summary.csv")).unwrap(),
            "precious"
        );
        // With --force a run folder coid wrote is replaced by a complete
        // new one (a user's folder never is: regression::).
        let c = cfg.to_str().unwrap();
        assert_ok(&fx.coid(&["run", "-q", "--config", c, "--out", "mine"]));
        let before = std::fs::read(fx.path("mine/summary.csv")).unwrap();
        let seed = ["--traffic-seed", "2"];
        let args = ["run", "-q", "--force", "--config", c, "--out", "mine"];
        assert_ok(&fx.coid(&[&args[..], &seed[..]].concat()));
        let after = std::fs::read(fx.path("mine/summary.csv")).unwrap();
        assert!(after.starts_with(b"method,") && after != before);
    }

    /// A command refused with one line, no panic, a non-zero exit.
    fn refused(out: &Output, expect: &str) {
        let err = stderr(out);
        assert!(!out.status.success(), "expected a refusal ({expect})");
        assert!(!err.contains("panicked"), "panic: {err}");
        assert_eq!(err.trim().lines().count(), 1, "not one line: {err}");
        assert!(err.contains(expect), "expected {expect:?} in: {err}");
    }

    /// `--force` replaces only what the same command wrote: never a
    /// user's folder (here the one holding the run's own config), nor a
    /// batch's or another command's results.
    #[test]
    fn force_replaces_only_results_of_the_same_kind() {
        let fx = Fixture::new();
        std::fs::create_dir_all(fx.path("mine")).unwrap();
        let cfg = fx.write(
            "mine/c.toml",
            &std::fs::read_to_string(fx.config("c.toml", 60.0, "")).unwrap(),
        );
        let c = cfg.to_str().unwrap();
        refused(
            &fx.coid(&["run", "-q", "--force", "--config", c, "--out", "mine"]),
            "coid did not write it",
        );
        assert!(cfg.is_file(), "the config was removed");
        assert_ok(&fx.coid(&["run", "-q", "--config", c, "--out", "r"]));
        refused(
            &fx.coid(&["eval", "-q", "--force", "--config", c, "--out", "r"]),
            "not an evaluation",
        );
        refused(
            &fx.coid(&["batch", "-q", "--config", c, "--runs", "1", "--out", "r"]),
            "not a batch folder",
        );
        refused(
            &fx.coid(&["scenarios", "-q", "--count", "1", "--out", "mine"]),
            "coid did not write it",
        );
        assert_ok(&fx.coid(&["run", "-q", "--force", "--config", c, "--out", "r"]));
    }

    /// Bounds that would exhaust memory or wrap around, and seeds SUMO
    /// cannot take, are refused before anything runs.
    #[test]
    fn out_of_range_arguments_are_refused() {
        let fx = Fixture::new();
        let c = fx.config("c.toml", 60.0, "");
        let c = c.to_str().unwrap();
        for (args, expect) in [
            (
                vec!["run", "--config", c, "--traffic-seed", "3000000000"],
                "3000000000",
            ),
            (
                vec!["batch", "--config", c, "--runs", "18446744073709551615"],
                "--runs",
            ),
            (vec!["batch", "--config", c, "--runs", "0"], "--runs"),
            (
                vec!["scenarios", "--first", "18446744073709551615", "--out", "s"],
                "--first",
            ),
        ] {
            let out = fx.coid(&args);
            assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
            assert!(stderr(&out).contains(expect), "{args:?}: {}", stderr(&out));
        }
        assert!(!fx.path("s").exists());
    }

    /// A run in which no two connected vehicles see a common object says
    /// so (and still writes its empty tables).
    #[test]
    fn a_run_without_instances_says_so() {
        let fx = Fixture::new();
        let cfg = fx.config("z.toml", 30.0, "[connected]\npenetration = 0.01\n");
        let out = fx.run(&cfg, "z");
        assert_ok(&out);
        assert!(stderr(&out).contains("no instance"), "{}", stderr(&out));
    }

    /// Output into a pipe whose reader is gone (`coid ... | head`) ends
    /// quietly: by SIGPIPE (13), as any Unix tool does, not by a panic.
    #[test]
    fn a_closed_pipe_ends_quietly() {
        use std::os::unix::process::ExitStatusExt;
        let mut child = coid_in(&repo())
            .args(["completions", "bash"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
        assert_eq!(out.status.signal(), Some(13), "{out:?}");
    }

    /// One shard folder given twice would count its runs twice.
    #[test]
    fn merge_refuses_a_shard_given_twice() {
        let fx = Fixture::new();
        let cfg = fx.config("m.toml", 60.0, "[matching]\nmethods = [\"oracle\"]\n");
        let c = cfg.to_str().unwrap();
        let args = [
            "batch", "-q", "--config", c, "--runs", "2", "--shard", "1/2", "--out", "s1",
        ];
        assert_ok(&fx.coid(&args));
        refused(
            &fx.coid(&["merge", "s1", "./s1", "--out", "m"]),
            "given twice",
        );
        assert!(!fx.path("m").exists());
    }
}

mod learned {
    use super::*;

    /// Real burn training on a small real data set (one SUMO run, one
    /// epoch), then a run that loads the weights it wrote.
    #[test]
    fn train_writes_loadable_weights_and_a_loss_curve() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "t.toml",
            80.0,
            &format!(
                "[train]\ntraffic_seeds = [201]\nepochs = 1\nmethods = [\"gcn-gm\"]\n[matching]\nmethods = [\"gcn-gm\", \"oracle\"]\nmodels_dir = {:?}\n[pose_noise]\nlevels = [\"gps\"]\n",
                fx.path("results/t-models").to_string_lossy()
            ),
        );
        // Without --out: a new folder, results/<config stem>-models, never
        // the shipped weights; a second time only with --force.
        let train = || fx.coid(&["train", "-q", "--config", cfg.to_str().unwrap()]);
        assert_ok(&train());
        for f in ["gcn-gm.bpk", "gcn-gm.toml", "gcn-gm_loss.csv"] {
            assert!(fx.path("results/t-models").join(f).is_file(), "{f} missing");
        }
        let again = train();
        assert!(
            !again.status.success() && stderr(&again).contains("already exists"),
            "{}",
            stderr(&again)
        );
        let curve = std::fs::read_to_string(fx.path("results/t-models/gcn-gm_loss.csv")).unwrap();
        // Epoch 0 holds the validation loss before training only.
        let loss: f64 = curve
            .lines()
            .find(|l| l.starts_with("1,"))
            .unwrap()
            .split(',')
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        assert!(loss.is_finite() && loss > 0.0, "{curve}");
        assert_ok(&fx.run(&cfg, "with-model"));
        let summary = read_csv(&fx.path("with-model/summary.csv"));
        assert!(strs(&summary, "method").iter().any(|m| m == "gcn-gm"));
    }

    /// Training lowers the loss on held-out validation runs of real SUMO
    /// data (one training run, one validation run; early stopping keeps
    /// the epoch with the lowest validation loss and records it).
    #[test]
    fn training_lowers_the_validation_loss_on_real_runs() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "t.toml",
            80.0,
            &format!(
                "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 3\npatience = 2\n\
                 methods = [\"gcn-gm\"]\n[matching]\nmodels_dir = {:?}\n[pose_noise]\nlevels = [\"gps\"]\n",
                fx.path("models").to_string_lossy()
            ),
        );
        assert_ok(&fx.coid(&[
            "train",
            "-q",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            "models",
        ]));
        let curve = read_csv(&fx.path("models/gcn-gm_loss.csv"));
        let v = f64s(&curve, "validation_loss");
        assert!(v.len() >= 2 && v.iter().all(|l| l.is_finite()), "{v:?}");
        let best = v[1..].iter().copied().fold(f64::INFINITY, f64::min);
        assert!(
            best < v[0],
            "validation loss before training {} never beaten: {v:?}",
            v[0]
        );
        let meta = std::fs::read_to_string(fx.path("models/gcn-gm.toml")).unwrap();
        assert!(meta.contains("best_epoch = "), "{meta}");
    }

    /// Two methods trained in two child processes give the same weights,
    /// losses and lambdas as one after the other in one process.
    #[test]
    fn training_in_child_processes_gives_the_same_models() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "t.toml",
            60.0,
            "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 1\n\
             methods = [\"gcn-gm\", \"dgmc\"]\n[pose_noise]\nlevels = [\"gps\"]\n",
        );
        let c = cfg.to_str().unwrap();
        let two = fx.coid(&["train", "-q", "--config", c, "--out", "two", "-w", "2"]);
        assert_ok(&two);
        assert_ok(&fx.coid(&["train", "-q", "--config", c, "--out", "one", "-w", "1"]));
        for m in ["gcn-gm", "dgmc"] {
            let read =
                |dir: &str, ext: &str| std::fs::read(fx.path(&format!("{dir}/{m}{ext}"))).unwrap();
            assert_eq!(
                read("two", ".bpk"),
                read("one", ".bpk"),
                "{m} weights differ"
            );
            assert_eq!(
                read("two", "_loss.csv"),
                read("one", "_loss.csv"),
                "{m} losses differ"
            );
            let lambda = |dir: &str| {
                String::from_utf8(read(dir, ".toml"))
                    .unwrap()
                    .lines()
                    .skip_while(|l| *l != "[validation]")
                    .find(|l| l.starts_with("lambda = "))
                    .map(str::to_owned)
            };
            assert!(lambda("two").is_some());
            assert_eq!(lambda("two"), lambda("one"));
        }
        assert!(stderr(&two).contains("trained dgmc"), "{}", stderr(&two));
    }

    /// Weights that are not the ones their record names (here another
    /// method's) are refused with one line, before anything runs.
    #[test]
    fn weights_that_do_not_match_their_record_are_refused() {
        let fx = Fixture::new();
        std::fs::create_dir_all(fx.path("models")).unwrap();
        for f in ["ours.bpk", "ours.toml"] {
            std::fs::copy(repo().join("models").join(f), fx.path("models").join(f)).unwrap();
        }
        std::fs::copy(repo().join("models/dgmc.bpk"), fx.path("models/ours.bpk")).unwrap();
        let cfg = fx.config(
            "w.toml",
            60.0,
            &format!(
                "[matching]\nmethods = [\"ours\"]\nmodels_dir = {:?}\n",
                fx.path("models").to_string_lossy()
            ),
        );
        let out = fx.run(&cfg, "w");
        assert!(!out.status.success());
        let err = stderr(&out);
        assert!(
            err.contains("not the ones recorded") && err.contains("ours"),
            "{err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!fx.path("w").exists());
    }

    #[test]
    fn missing_weights_are_a_clear_error() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "m.toml",
            60.0,
            &format!(
                "[matching]\nmethods = [\"ours\"]\nmodels_dir = {:?}\n",
                fx.path("nowhere").to_string_lossy()
            ),
        );
        let out = fx.run(&cfg, "out");
        assert!(!out.status.success());
        let err = stderr(&out);
        assert!(err.contains("ours") && err.contains("coid train"), "{err}");
        assert!(!err.contains("panicked"));
    }

    /// The shipped default weights on a small fixed test set (two test runs,
    /// never used in training or validation) at 1.2 m pose noise: the full
    /// method must beat the strongest baseline, GPS+appearance Hungarian,
    /// in F1.
    #[test]
    fn shipped_model_beats_gps_appearance_hungarian_at_gps_noise() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "e.toml",
            130.0,
            "[pose_noise]\nlevels = [\"gps\"]\n[eval]\ntraffic_seeds = [1, 2]\n",
        );
        assert_ok(&fx.coid(&[
            "eval",
            "-q",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            "ev",
        ]));
        let t1 = read_csv(&fx.path("ev/table1.csv"));
        let (m, f1) = (strs(&t1, "method"), f64s(&t1, "f1"));
        let f1_of = |name: &str| f1[m.iter().position(|x| x == name).unwrap()];
        assert!(
            f1_of("ours") > f1_of("gps-app-hungarian"),
            "ours F1 {} vs gps-app-hungarian F1 {}",
            f1_of("ours"),
            f1_of("gps-app-hungarian")
        );
        for f in [
            "table2.csv",
            "table3.csv",
            "lambda_sweep.csv",
            "case_study.csv",
            "summary.md",
            "calibration.csv",
            "lambda_sweep.svg",
            "error_cdf.svg",
            "f1_per_method.svg",
            "reliability_ours.svg",
        ] {
            assert!(fx.path("ev").join(f).is_file(), "{f} missing");
        }
        let cal = read_csv(&fx.path("ev/calibration.csv"));
        for c in ["method", "pose_noise", "ece", "brier", "auroc"] {
            assert!(cal.column(c).is_ok(), "calibration.csv lacks {c}");
        }
        // Every method identified pairs here, so each row is measured on
        // them: a count above zero and the three measures in [0, 1].
        let (n, ece) = (f64s(&cal, "n_pairs"), f64s(&cal, "ece"));
        let (brier, auroc) = (f64s(&cal, "brier"), f64s(&cal, "auroc"));
        for (k, name) in strs(&cal, "method").iter().enumerate() {
            assert!(n[k] > 0.0, "{name}: no identified pairs");
            for v in [ece[k], brier[k]] {
                assert!((0.0..=1.0).contains(&v), "{name}: {v}");
            }
            // The oracle is never wrong, so the AUROC is undefined for it.
            assert_eq!(auroc[k].is_nan(), name == "oracle", "{name}: {}", auroc[k]);
        }
        for (plot, w, h) in [
            ("lambda_sweep", 420, 380),
            ("error_cdf", 420, 380),
            ("reliability_ours", 420, 380),
            ("f1_per_method", 990, 420),
        ] {
            let img = image::open(fx.path("ev").join(format!("{plot}.png")))
                .unwrap()
                .to_rgb8();
            assert_eq!(img.height(), h, "{plot}");
            assert_eq!(img.width() % w, 0, "{plot}: width {}", img.width());
            let ink = img.pixels().filter(|p| p.0 != [255, 255, 255]).count() as f64;
            let share = ink / f64::from(img.width() * img.height());
            assert!(share > 0.03 && share < 0.9, "{plot}: ink share {share}");
        }
    }
}

mod likelihood {
    use coid_sim::config::Settings;
    use coid_sim::matching::deep::arch::DeepMethod;
    use coid_sim::matching::deep::decision::Decision;
    use coid_sim::matching::deep::{DeepMatcher, Inference};
    use coid_sim::matching::{GpsHungarian, Matcher};
    use coid_sim::pipeline;

    use super::*;

    /// Untrained (the residual's gate at zero), every deep method that uses
    /// positions decides exactly as GPS+appearance Hungarian does, pair for
    /// pair, on every instance of a real scene (the shipped intersection
    /// through the real bridge, 60 s, every pose-noise level): they start
    /// from the same likelihood and the same assignment.
    #[test]
    fn the_untrained_residual_reproduces_gps_appearance_hungarian_on_a_real_scene() {
        let fx = Fixture::new();
        let settings = Settings::load(&fx.config("u.toml", 60.0, "")).unwrap();
        let hungarian = GpsHungarian {
            gate_chi2: settings.matching.gate_chi2,
            appearance: true,
        };
        let run = Inference {
            samples: 4,
            threshold: None,
            decision: Decision::Assignment,
            temperature: 1.0,
            seed: 1,
            gate_chi2: settings.matching.gate_chi2,
        };
        let deep: Vec<DeepMatcher> = [
            DeepMethod::Ours,
            DeepMethod::CoidNon,
            DeepMethod::CoidUnc,
            DeepMethod::Dgmc,
            DeepMethod::GcnGm,
        ]
        .iter()
        .map(|&m| DeepMatcher::untrained(m.method(), m.architecture(), 7, run))
        .collect();
        let pairs =
            |m: &dyn Matcher, pair: &coid_sim::evaluate::PairAtLevel| -> Vec<(usize, usize)> {
                let id = m.identify(&pair.first.view, &pair.second.view);
                id.matches.iter().map(|c| (c.a, c.b)).collect()
            };
        let mut compared = 0;
        pipeline::simulate(
            &settings,
            |_| {},
            |inst| {
                for level in &settings.pose_noise {
                    let pair = inst.at_level(settings.seeds.sensor, level);
                    let expected = pairs(&hungarian, &pair);
                    for m in &deep {
                        assert_eq!(
                            pairs(m, &pair),
                            expected,
                            "{:?} at step {}",
                            m.method,
                            inst.frame.step
                        );
                    }
                    compared += expected.len();
                }
                Ok(())
            },
        )
        .unwrap();
        assert!(compared > 100, "only {compared} pairs compared");
    }
}

mod batch {
    use super::*;
    use std::time::{Duration, Instant};

    /// A fast batch config: short runs, cheap methods.
    fn fast_config(fx: &Fixture, sumocfg: &Path) -> PathBuf {
        fx.write(
            "b.toml",
            &format!(
                "[scenario]\nsumocfg = {:?}\njunction = \"C\"\nend_s = 75\n[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n",
                sumocfg.to_string_lossy()
            ),
        )
    }

    fn batch(
        fx: &Fixture,
        cfg: &Path,
        runs: &str,
        workers: &str,
        out: &str,
        extra: &[&str],
    ) -> Output {
        let mut args = vec![
            "batch",
            "-q",
            "--config",
            cfg.to_str().unwrap(),
            "--runs",
            runs,
            "--workers",
            workers,
            "--out",
            out,
        ];
        args.extend_from_slice(extra);
        fx.coid(&args)
    }

    fn bytes(fx: &Fixture, dir: &str) -> Vec<u8> {
        std::fs::read(fx.path(dir).join("summary.csv")).unwrap()
    }

    /// Starts `coid batch` of `runs` runs on one worker into `out` without
    /// waiting for it.
    fn spawn_batch(fx: &Fixture, cfg: &Path, runs: &str, out: &str) -> std::process::Child {
        coid_in(fx.dir.path())
            .args([
                "batch",
                "-q",
                "--config",
                cfg.to_str().unwrap(),
                "--runs",
                runs,
            ])
            .args(["--workers", "1", "--out", out])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    }

    /// Waits until the first run of the batch in `out` is complete.
    fn wait_for_first_run(fx: &Fixture, out: &str) {
        let first = fx.path(&format!("{out}/runs/run-000000/summary.csv"));
        let deadline = Instant::now() + Duration::from_secs(60);
        wait_until(deadline, "first run never finished", || first.is_file());
    }

    #[test]
    fn one_and_two_workers_give_identical_aggregates_with_intervals() {
        let fx = Fixture::new();
        let cfg = fast_config(&fx, &shipped_sumocfg());
        assert_ok(&batch(&fx, &cfg, "4", "1", "w1", &[]));
        assert_ok(&batch(&fx, &cfg, "4", "2", "w2", &[]));
        assert_eq!(bytes(&fx, "w1"), bytes(&fx, "w2"));
        let s = read_csv(&fx.path("w1/summary.csv"));
        for c in ["de_fused_m_ci95", "f1_ci95", "n_runs"] {
            assert!(s.column(c).is_ok(), "{c} missing");
        }
        for i in 0..4 {
            assert!(
                fx.path(&format!("w1/runs/run-{i:06}/summary.csv"))
                    .is_file()
            );
        }
    }

    #[test]
    fn a_killed_batch_resumes_to_the_same_bytes() {
        let fx = Fixture::new();
        let cfg = fast_config(&fx, &shipped_sumocfg());
        assert_ok(&batch(&fx, &cfg, "5", "2", "whole", &[]));
        let mut child = spawn_batch(&fx, &cfg, "5", "killed");
        // Kill it once the first run is complete, mid-batch.
        wait_for_first_run(&fx, "killed");
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        assert!(
            !fx.path("killed/summary.csv").exists() || bytes(&fx, "killed") != bytes(&fx, "whole")
        );
        // Only the missing runs run again: the finished one is left alone.
        let finished = fx.path("killed/runs/run-000000/summary.csv");
        let before = std::fs::metadata(&finished).unwrap().modified().unwrap();
        assert_ok(&batch(&fx, &cfg, "5", "2", "killed", &[]));
        assert_eq!(
            std::fs::metadata(&finished).unwrap().modified().unwrap(),
            before
        );
        assert_eq!(bytes(&fx, "killed"), bytes(&fx, "whole"));
    }

    /// Killing `coid batch` ends its workers too (no orphans).
    #[test]
    fn the_workers_of_a_killed_batch_end_with_it() {
        let fx = Fixture::new();
        let cfg = fx.config("slow.toml", 200.0, "[connected]\npenetration = 0.3\n");
        let mut parent = coid_in(fx.dir.path())
            .args([
                "batch",
                "-q",
                "--config",
                cfg.to_str().unwrap(),
                "--runs",
                "4",
            ])
            .args(["--workers", "2", "--out", "b"])
            .spawn()
            .unwrap();
        let children_of = |pid: u32| -> Vec<u32> {
            let tasks = format!("/proc/{pid}/task");
            std::fs::read_dir(tasks)
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|t| std::fs::read_to_string(t.path().join("children")).ok())
                .flat_map(|c| {
                    c.split_whitespace()
                        .filter_map(|p| p.parse().ok())
                        .collect::<Vec<u32>>()
                })
                .collect()
        };
        let started = Instant::now();
        let mut workers = Vec::new();
        wait_until(
            started + Duration::from_secs(60),
            "no workers started",
            || {
                workers = children_of(parent.id());
                workers.len() == 2
            },
        );
        parent.kill().unwrap(); // SIGKILL: no chance to clean up
        parent.wait().unwrap();
        let gone = |pid: &u32| {
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map_or(true, |s| s.split_whitespace().nth(2) == Some("Z"))
        };
        let orphans = format!("orphaned workers {workers:?}");
        wait_until(started + Duration::from_secs(90), &orphans, || {
            workers.iter().all(gone)
        });
    }

    /// A batch is what its configuration says, not where it lies: a
    /// resume after an edit is refused, shards of two different batches
    /// do not merge, and the same config at another path resumes and
    /// merges.
    #[test]
    fn a_batch_is_identified_by_content_not_by_path() {
        let fx = Fixture::new();
        let cfg = fast_config(&fx, &shipped_sumocfg());
        let text = std::fs::read_to_string(&cfg).unwrap();
        assert_ok(&batch(&fx, &cfg, "2", "1", "b", &["--shard", "1/2"]));
        // The same config at another path: the other shard, and a resume.
        std::fs::create_dir_all(fx.path("elsewhere")).unwrap();
        let moved = fx.write("elsewhere/b.toml", &text);
        assert_ok(&batch(&fx, &moved, "2", "1", "b2", &["--shard", "2/2"]));
        assert_ok(&batch(&fx, &moved, "2", "1", "b", &["--shard", "1/2"]));
        assert_ok(&fx.coid(&["merge", "b", "b2", "--out", "merged"]));
        // An edit (one setting) makes another batch.
        let edited = fx.write(
            "edited.toml",
            &format!("{text}[sensor]\ncolour_sigma = 0.07\n"),
        );
        let out = batch(&fx, &edited, "2", "1", "b", &["--shard", "1/2"]);
        assert!(!out.status.success());
        assert!(
            stderr(&out).contains("has changed since"),
            "{}",
            stderr(&out)
        );
        assert_eq!(stderr(&out).trim().lines().count(), 1, "{}", stderr(&out));
        assert_ok(&batch(&fx, &edited, "2", "1", "e2", &["--shard", "2/2"]));
        let out = fx.coid(&["merge", "b", "e2", "--out", "mixed"]);
        assert!(!out.status.success());
        assert!(stderr(&out).contains("different batch"), "{}", stderr(&out));
        assert_eq!(stderr(&out).trim().lines().count(), 1, "{}", stderr(&out));
        assert!(!fx.path("mixed").exists());
    }

    /// A resume checks every run folder: a summary cut short or a missing
    /// objects.parquet is run again, and the aggregate is as if nothing
    /// happened.
    #[test]
    fn a_resumed_batch_reruns_damaged_runs() {
        let fx = Fixture::new();
        let cfg = fast_config(&fx, &shipped_sumocfg());
        assert_ok(&batch(&fx, &cfg, "3", "2", "whole", &[]));
        assert_ok(&batch(&fx, &cfg, "3", "2", "damaged", &[]));
        let run = |i: usize, f: &str| fx.path(&format!("damaged/runs/run-{i:06}/{f}"));
        let summary = std::fs::read_to_string(run(0, "summary.csv")).unwrap();
        std::fs::write(run(0, "summary.csv"), &summary[..summary.len() * 2 / 3]).unwrap();
        std::fs::remove_file(run(1, "objects.parquet")).unwrap();
        let untouched = std::fs::metadata(run(2, "summary.csv"))
            .unwrap()
            .modified()
            .unwrap();
        assert_ok(&batch(&fx, &cfg, "3", "2", "damaged", &[]));
        assert_eq!(bytes(&fx, "damaged"), bytes(&fx, "whole"));
        assert!(run(1, "objects.parquet").is_file());
        assert_eq!(
            std::fs::metadata(run(2, "summary.csv"))
                .unwrap()
                .modified()
                .unwrap(),
            untouched
        );
    }

    #[test]
    fn merged_shards_equal_the_unsharded_batch() {
        let fx = Fixture::new();
        let cfg = fast_config(&fx, &shipped_sumocfg());
        assert_ok(&batch(&fx, &cfg, "5", "2", "all", &[]));
        assert_ok(&batch(&fx, &cfg, "5", "1", "s1", &["--shard", "1/2"]));
        assert_ok(&batch(&fx, &cfg, "5", "1", "s2", &["--shard", "2/2"]));
        assert_ok(&fx.coid(&["merge", "s1", "s2", "--out", "merged"]));
        assert_eq!(bytes(&fx, "merged"), bytes(&fx, "all"));
        let report = |dir: &str| std::fs::read(fx.path(dir).join("summary.md")).unwrap();
        assert_eq!(report("merged"), report("all"));
    }

    #[test]
    fn failing_runs_are_reported_and_do_not_poison_the_aggregate() {
        let fx = Fixture::new();
        // A private copy of the scenario, removed once the first run is done.
        let scen = fx.path("scenario");
        std::fs::create_dir_all(&scen).unwrap();
        for e in std::fs::read_dir(repo().join("sumo_nets/intersection")).unwrap() {
            let p = e.unwrap().path();
            std::fs::copy(&p, scen.join(p.file_name().unwrap())).unwrap();
        }
        let cfg = fast_config(&fx, &scen.join("intersection.sumocfg"));
        let child = spawn_batch(&fx, &cfg, "4", "f");
        wait_for_first_run(&fx, "f");
        std::fs::remove_file(scen.join("intersection.sumocfg")).unwrap();
        let out = child.wait_with_output().unwrap();
        let err = stderr(&out);
        assert!(!out.status.success(), "{err}");
        assert!(
            err.contains("failed") && err.contains("no such file"),
            "{err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        let s = read_csv(&fx.path("f/summary.csv"));
        let n_runs = f64s(&s, "n_runs");
        assert!(
            n_runs.iter().all(|&n| (1.0..4.0).contains(&n)),
            "{n_runs:?}"
        );
        assert!(f64s(&s, "f1").iter().all(|v| v.is_finite()));
    }
}

mod pictures {
    use super::*;

    #[test]
    fn render_draws_real_instances_as_png_and_svg() {
        let fx = Fixture::new();
        let cfg = fx.config("r.toml", 80.0, "");
        let out = fx.coid(&[
            "render",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            "pics",
            "--instances",
            "0,1",
        ]);
        assert_ok(&out);
        for name in ["instance-0000", "instance-0001"] {
            let png = fx.path("pics").join(format!("{name}.png"));
            let img = image::open(&png).unwrap().to_rgb8();
            assert_eq!((img.width(), img.height()), (1000, 1000));
            let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
            assert!(colours.len() > 20, "{name}: only {} colours", colours.len());
            assert!(fx.path("pics").join(format!("{name}.svg")).is_file());
        }
        let bad = fx.coid(&[
            "render",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            "none",
            "--instances",
            "100000",
        ]);
        assert!(!bad.status.success());
        assert!(stderr(&bad).contains("no instance"), "{}", stderr(&bad));
        assert!(!fx.path("none").exists());
    }
}

mod scenarios {
    use super::*;

    /// Every file of a folder, by name.
    fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
        let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| {
                let p = e.unwrap().path();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                (name, std::fs::read(&p).unwrap())
            })
            .collect();
        out.sort();
        out
    }

    /// The same seed gives the same bytes (the SUMO net included), another
    /// seed other scenarios, and every generated scenario runs as its
    /// folder's config says, with only the simulated time shortened.
    #[test]
    fn generation_is_deterministic_and_every_scenario_runs() {
        let fx = Fixture::new();
        for out in ["a", "b"] {
            assert_ok(&fx.coid(&[
                "scenarios",
                "-q",
                "--count",
                "3",
                "--seed",
                "4",
                "--out",
                out,
            ]));
        }
        assert_ok(&fx.coid(&[
            "scenarios",
            "-q",
            "--count",
            "1",
            "--seed",
            "5",
            "--out",
            "c",
        ]));
        for s in ["s000", "s001", "s002"] {
            let (a, b) = (files(&fx.path("a").join(s)), files(&fx.path("b").join(s)));
            let names: Vec<&str> = a.iter().map(|f| f.0.as_str()).collect();
            assert!(names.contains(&"net.net.xml") && names.contains(&"coid.toml"));
            assert_eq!(a, b, "{s} differs between two generations");
        }
        assert_ne!(files(&fx.path("a/s000")), files(&fx.path("c/s000")));
        // Again into an existing folder: refused without --force.
        let again = fx.coid(&[
            "scenarios",
            "-q",
            "--count",
            "1",
            "--seed",
            "4",
            "--out",
            "a",
        ]);
        assert!(!again.status.success() && stderr(&again).contains("exists"));
        let mut instances = 0.0;
        for s in ["s000", "s001", "s002"] {
            let dir = fx.path("a").join(s);
            let own = std::fs::read_to_string(dir.join("coid.toml")).unwrap();
            let cfg = dir.join("short.toml");
            // Shorter, with more connected vehicles, so that 60 s give
            // instances.
            let short = own
                .replace("end_s = 150.0", "end_s = 60.0")
                .replace("penetration = 0.1", "penetration = 0.5")
                + "[matching]\nmethods = [\"oracle\", \"gps-hungarian\"]\n";
            std::fs::write(&cfg, short).unwrap();
            let out = format!("run-{s}");
            assert_ok(&fx.run(&cfg, &out));
            let summary = read_csv(&fx.path(&out).join("summary.csv"));
            // A run without instances has no rows.
            instances += f64s(&summary, "n_instances")
                .first()
                .copied()
                .unwrap_or(0.0);
        }
        assert!(instances > 0.0, "no instance in three generated scenarios");
    }
}

mod suite {
    use super::*;

    /// `eval --suite`: tables per scenario and pooled over every run (the
    /// pooled run count is the sum), from the shipped intersection and a
    /// generated scenario; a config with other pose-noise levels is refused.
    #[test]
    fn eval_over_a_suite_writes_per_scenario_and_pooled_tables() {
        let fx = Fixture::new();
        let levels = "[pose_noise]\nlevels = [\"none\", \"gps\"]\n\
                      [matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n";
        let base = fx.config(
            "base.toml",
            60.0,
            &format!("{levels}[eval]\ntraffic_seeds = [1, 2]\n"),
        );
        assert_ok(&fx.coid(&[
            "scenarios",
            "-q",
            "--count",
            "1",
            "--seed",
            "3",
            "--out",
            "fam",
        ]));
        let own = std::fs::read_to_string(fx.path("fam/s000/coid.toml")).unwrap();
        let generated = fx.write(
            "fam/s000/short.toml",
            &(own
                .replace("end_s = 150.0", "end_s = 60.0")
                .replace("penetration = 0.1", "penetration = 0.3")
                + &format!("{levels}[eval]\ntraffic_seeds = [3]\n")),
        );
        let (b, g) = (base.to_str().unwrap(), generated.to_str().unwrap());
        assert_ok(&fx.coid(&["eval", "-q", "--config", b, "--suite", g, "--out", "ev"]));
        let runs = |dir: &str| f64s(&read_csv(&fx.path(dir).join("table1.csv")), "n_runs")[0];
        assert_eq!(runs("ev/base"), 2.0);
        assert_eq!(runs("ev/short"), 1.0);
        assert_eq!(runs("ev/pooled"), 3.0);
        // eval runs the configured methods only.
        let mut methods = strs(&read_csv(&fx.path("ev/pooled/table1.csv")), "method");
        methods.dedup();
        assert_eq!(methods, ["gps-hungarian", "oracle"]);
        let md = std::fs::read_to_string(fx.path("ev/pooled/summary.md")).unwrap();
        assert!(md.contains("base, short"), "{md}");
        // Other pose-noise levels cannot be pooled.
        let other = fx.config("other.toml", 60.0, "[pose_noise]\nlevels = [\"gps\"]\n");
        let o = other.to_str().unwrap();
        let refused = fx.coid(&["eval", "-q", "--config", b, "--suite", o, "--out", "ev2"]);
        assert!(!refused.status.success());
        let err = stderr(&refused);
        assert!(
            err.contains("pose-noise levels") && !err.contains("panicked"),
            "{err}"
        );
        assert!(!fx.path("ev2").exists());
    }
}

mod family_roles {
    use super::*;

    /// `[train] scenarios` and `validation_scenarios` feed `coid train`
    /// (their runs are collected, the lambda is validated on the held-out
    /// scenario, both are recorded beside the weights), and `[eval]
    /// scenarios` joins `coid eval` as its own table and the pooled one.
    #[test]
    fn train_and_eval_use_the_scenario_lists() {
        let fx = Fixture::new();
        assert_ok(&fx.coid(&[
            "scenarios",
            "-q",
            "--count",
            "3",
            "--seed",
            "21",
            "--out",
            "fam",
        ]));
        for k in 0..3 {
            let p = fx.path(&format!("fam/s00{k}/coid.toml"));
            let own = std::fs::read_to_string(&p).unwrap();
            let short = own
                .replace("end_s = 150.0", "end_s = 50.0")
                .replace("penetration = 0.1", "penetration = 0.5");
            std::fs::write(&p, short).unwrap();
        }
        let cfg = fx.config(
            "t.toml",
            60.0,
            "[pose_noise]\nlevels = [\"gps\"]\n\
             [train]\ntraffic_seeds = [101]\nvalidation_seeds = [125]\nmethods = [\"gcn-gm\"]\n\
             epochs = 1\nscenarios = [\"fam/s000/coid.toml\"]\n\
             validation_scenarios = [\"fam/s001/coid.toml\"]\nruns_per_scenario = 1\n\
             [eval]\ntraffic_seeds = [1]\nscenarios = [\"fam/s002/coid.toml\"]\n",
        );
        let c = cfg.to_str().unwrap();
        let trained = fx.coid(&["train", "-q", "--config", c, "--out", "models"]);
        assert_ok(&trained);
        assert!(
            stderr(&trained).contains("from 2 runs"),
            "{}",
            stderr(&trained)
        );
        let meta = std::fs::read_to_string(fx.path("models/gcn-gm.toml")).unwrap();
        assert!(
            meta.contains("train_scenarios") && meta.contains("s000"),
            "{meta}"
        );
        assert!(
            meta.contains("validation_scenarios") && meta.contains("s001"),
            "{meta}"
        );
        assert_ok(&fx.coid(&["eval", "-q", "--config", c, "--out", "ev"]));
        for dir in ["ev/t", "ev/s002", "ev/pooled"] {
            assert!(fx.path(dir).join("table1.csv").is_file(), "{dir}");
        }
    }
}

mod export_score {
    use super::*;

    /// A short config with the fast methods, two test runs.
    fn small(fx: &Fixture) -> PathBuf {
        fx.config(
            "small.toml",
            60.0,
            "[matching]\nmethods = [\"gps-hungarian\", \"gps-app-hungarian\", \"oracle\"]\n\
             [eval]\ntraffic_seeds = [1, 2]\n",
        )
    }

    /// `coid export` of the test runs into `ex`, with GPS-Hungarian's matches.
    fn export(fx: &Fixture, config: &Path) {
        let c = config.to_str().unwrap();
        assert_ok(&fx.coid(&[
            "export",
            "-q",
            "-c",
            c,
            "--splits",
            "test",
            "--with-matches",
            "gps-hungarian",
            "-o",
            "ex",
        ]));
    }

    /// `coid score` of `matches` (made from the export `ex`).
    fn score(fx: &Fixture, config: &Path, matches: &str, out: &str) -> Output {
        let c = config.to_str().unwrap();
        let args = ["score", "-q", "-c", c, "--matches", matches, "-o", out];
        fx.coid(&[&args[..], &["--export", "ex"]].concat())
    }

    /// The lines of a table for `method`, without the method.
    fn rows(fx: &Fixture, dir: &str, file: &str, method: &str) -> Vec<String> {
        let text = std::fs::read_to_string(fx.path(dir).join(file)).unwrap();
        let prefix = format!("{method},");
        text.lines()
            .filter_map(|l| l.strip_prefix(&prefix).map(str::to_owned))
            .collect()
    }

    /// Export then score: GPS-Hungarian's exported matches score exactly
    /// as GPS-Hungarian (P/R/F1, displacement errors with both fusion
    /// variants, calibration, consistency, all-view fusion), and the
    /// exported true pairs exactly as the oracle; the export says what it
    /// holds.
    #[test]
    fn exported_matches_reproduce_the_built_in_rows() {
        let fx = Fixture::new();
        let config = small(&fx);
        export(&fx, &config);
        let runs = read_parquet(&fx.path("ex/runs.parquet"));
        assert_eq!(strs(&runs, "split"), vec!["test", "test"]);
        assert_eq!(f64s(&runs, "schema_version"), vec![2.0, 2.0]);
        let instances: f64 = f64s(&runs, "n_instances").iter().sum();
        assert!(instances > 0.0);
        let levels = read_parquet(&fx.path("ex/instances.parquet")).height() as f64;
        assert_eq!(levels, 3.0 * instances);
        let nodes = read_parquet(&fx.path("ex/nodes.parquet"));
        assert_eq!(
            nodes.height(),
            read_parquet(&fx.path("ex/truth.parquet")).height()
        );
        assert!(
            std::fs::read_to_string(fx.path("ex/schema.md"))
                .unwrap()
                .contains("schema version 2")
        );
        assert_ok(&score(
            &fx,
            &config,
            "ex/matches-gps-hungarian.parquet",
            "s1",
        ));
        assert_ok(&score(&fx, &config, "ex/true_pairs.parquet", "s2"));
        for file in [
            "table1.csv",
            "errors.csv",
            "calibration.csv",
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
            rows(&fx, "s1", "table1.csv", "external"),
            rows(&fx, "s1", "table1.csv", "gps-app-hungarian")
        );
    }

    /// The Python example (polars and numpy, through the project's
    /// environment) reads the export, writes matches, and prints the
    /// precision, recall and F1 its rule implies; `coid score` finds the
    /// same numbers for it.
    #[test]
    fn the_python_example_scores_what_its_rule_implies() {
        let fx = Fixture::new();
        let config = small(&fx);
        export(&fx, &config);
        let venv = std::env::var_os("COID_VENV")
            .map(PathBuf::from)
            .unwrap_or_else(|| repo().join(".venv"));
        let out = Command::new(venv.join("bin/python"))
            .arg(repo().join("examples/nearest_match.py"))
            .arg(fx.path("ex"))
            .arg("--out")
            .arg(fx.path("nm.parquet"))
            .env_remove("PYTHONHOME")
            .output()
            .expect("run python");
        assert_ok(&out);
        let printed = String::from_utf8_lossy(&out.stdout).into_owned();
        assert_ok(&score(&fx, &config, "nm.parquet", "s"));
        let table = read_csv(&fx.path("s/table1.csv"));
        let (methods, levels) = (strs(&table, "method"), strs(&table, "pose_noise"));
        let mut checked = 0;
        for line in printed.lines().filter(|l| l.contains(" f1 ")) {
            let words: Vec<&str> = line.split_whitespace().collect();
            let level = words[0].trim_end_matches(':');
            let k = (0..table.height())
                .find(|&k| methods[k] == "external" && levels[k] == level)
                .unwrap_or_else(|| panic!("no external row at {level}"));
            for (name, at) in [("precision", 2), ("recall", 4), ("f1", 6)] {
                let python: f64 = words[at].parse().unwrap();
                let coid = f64s(&table, name)[k];
                assert!(
                    (python - coid).abs() < 1e-6,
                    "{name} at {level}: {python} vs {coid}"
                );
            }
            checked += 1;
        }
        assert_eq!(checked, 3, "{printed}");
    }

    /// A matches file that does not fit the exported instances is refused
    /// with one line and a non-zero exit, and nothing is written.
    #[test]
    fn a_matches_file_that_does_not_fit_is_refused_in_one_line() {
        let fx = Fixture::new();
        let config = small(&fx);
        export(&fx, &config);
        let run = f64s(&read_parquet(&fx.path("ex/runs.parquet")), "run")[0] as u64;
        let cases = [
            (
                format!("run,instance,a,b\n{run},0,999,0\n"),
                "a match pairs nodes 999",
            ),
            (
                format!("run,instance,a,b\n{run},100000,0,0\n"),
                "matches name instance 100000",
            ),
            ("run,instance,a,b\n0,0,0,0\n".into(), "a train run"),
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
            let err = stderr(&o);
            assert_eq!(o.status.code(), Some(1), "{body}: {err}");
            assert!(err.contains(expect), "{body}: {err}");
            assert_eq!(err.trim_end().lines().count(), 1, "{err}");
            assert!(!fx.path("s").exists());
        }
    }
}

mod v2x {
    use super::*;

    fn track(fx: &Fixture, config: &Path, out: &str) -> DataFrame {
        assert_ok(&fx.coid(&["track", "-q", "-c", config.to_str().unwrap(), "-o", out]));
        read_csv(&fx.path(out).join("tracking.csv"))
    }

    /// `coid track` on real SUMO at 10 Hz: the same seed gives the same
    /// bytes; with a clean camera (no noise, misses or false positives)
    /// the trackers are far better than with the calibrated one (MOTA >
    /// 0.7; what is left: the 3 hits before a track is confirmed, and id
    /// switches on turns, where the tiny measurement noise makes the gate
    /// narrow); a message goes out at
    /// every step at 10 Hz and at every tenth step at 1 Hz; the channel
    /// loses about what it is told to; the receivers' matching per message
    /// and over time is nearly always right with a clean camera.
    #[test]
    fn trackers_and_messages_follow_the_settings() {
        let fx = Fixture::new();
        let base = "[connected]\npenetration = 0.3\n";
        let cfg = fx.config("t.toml", 60.0, base);
        let t = track(&fx, &cfg, "a");
        assert_ok(&fx.coid(&["track", "-q", "-c", cfg.to_str().unwrap(), "-o", "b"]));
        assert_eq!(
            std::fs::read(fx.path("a/tracking.csv")).unwrap(),
            std::fs::read(fx.path("b/tracking.csv")).unwrap()
        );
        let last = t.height() - 1;
        assert_eq!(strs(&t, "ego_id")[last], "all");
        // Fusing every reception into a running estimate as if it were
        // independent counts the same information again and again: its
        // claimed covariance is far too small (NEES well above 2), and
        // covariance intersection's is not.
        let a = read_csv(&fx.path("a/association.csv"));
        let (nees, nees_ci) = (
            f64s(&a, "recursive_nees_fused")[1],
            f64s(&a, "recursive_nees_fused_ci")[1],
        );
        assert!(nees > 2.0 * nees_ci && nees_ci < 5.0, "{a}");
        let (steps, messages) = (f64s(&t, "steps")[last], f64s(&t, "messages")[last]);
        assert!(steps > 100.0 && messages == steps, "{t}");
        let (delivered, lost) = (f64s(&t, "delivered")[last], f64s(&t, "lost")[last]);
        let loss = lost / (delivered + lost);
        assert!(
            delivered > 200.0 && (loss - 0.1).abs() < 0.04,
            "{delivered} {loss}"
        );
        let clean = fx.config(
            "c.toml",
            60.0,
            &format!(
                "{base}[sensor]\nrange_sigma_base_m = 0.01\nrange_sigma_per_m = 0.0\n\
                 bearing_sigma_base_deg = 0.01\nbearing_sigma_per_m_deg = 0.0\nmiss_prob_base = 0.0\n\
                 miss_prob_at_max_range = 0.0\nmiss_prob_occlusion = 0.0\nfalse_positives_per_frame = 0.0\n\
                 [v2x.cpm]\nrate_hz = 1.0\n"
            ),
        );
        let c = track(&fx, &clean, "clean");
        let mota = f64s(&c, "mota")[c.height() - 1];
        assert!(mota > 0.7 && mota > f64s(&t, "mota")[last] + 0.2, "{c}");
        // The receivers match what arrives against their own tracks: with a
        // clean camera both decisions are nearly always right.
        let a = read_csv(&fx.path("clean/association.csv"));
        assert_eq!(strs(&a, "association"), ["per-message", "over-time"]);
        assert!(f64s(&a, "receptions")[0] > 20.0, "{a}");
        assert!(f64s(&a, "f1").iter().all(|&f| f > 0.85), "{a}");
        let (steps, messages) = (f64s(&c, "steps"), f64s(&c, "messages"));
        for (s, m) in steps.iter().zip(&messages).take(c.height() - 1) {
            assert!((m - (s / 10.0).ceil()).abs() <= 1.0, "{c}");
        }
    }

    /// Without latency compensation a message's objects are where they
    /// were 100-200 ms ago: the oracle's single and fused errors at exact
    /// poses grow against `fresh` (the same run, compensated).
    fn stale_messages_err_more(fx: &Fixture, methods: &str, fresh: &DataFrame) {
        let stale = fx.config(
            "stale.toml",
            90.0,
            &format!("{methods}[v2x]\nmode = \"cpm\"\ncompensate_latency = false\n"),
        );
        assert_ok(&fx.run(&stale, "stale"));
        let z = read_csv(&fx.path("stale/summary.csv"));
        let at_none = |df: &DataFrame, col: &str| {
            let (m, l, v) = (strs(df, "method"), strs(df, "pose_noise"), f64s(df, col));
            (0..df.height())
                .find(|&k| m[k] == "oracle" && l[k] == "none")
                .map(|k| v[k])
                .unwrap()
        };
        for col in ["de_single_covis_m", "de_fused_covis_m"] {
            assert!(
                at_none(&z, col) > at_none(fresh, col) + 0.05,
                "{col}: {z} {fresh}"
            );
        }
    }

    /// `[v2x] mode = "cpm"` in runs: SUMO at 10 Hz, trackers, CPMs and the
    /// channel; every sampled reception is an instance whose message side
    /// is named `<sender> -> <receiver>`. The same bytes on 1 and 2
    /// threads and on 1 and 2 batch workers; the oracle is right and its
    /// fusion helps; without latency compensation the errors grow; a
    /// reception is drawn; synchronized matching runs with more vehicles.
    #[test]
    fn cpm_mode_runs_batches_and_draws() {
        let fx = Fixture::new();
        let methods = "[matching]\nmethods = [\"gps-app-hungarian\", \"oracle\"]\n";
        let cfg = fx.config("c.toml", 90.0, &format!("{methods}[v2x]\nmode = \"cpm\"\n"));
        let c = cfg.to_str().unwrap();
        for (threads, out) in [("1", "t1"), ("2", "t2")] {
            assert_ok(&fx.coid(&["run", "-q", "-c", c, "-o", out, "--threads", threads]));
        }
        for f in ["summary.csv", "objects.parquet"] {
            assert_eq!(
                std::fs::read(fx.path("t1").join(f)).unwrap(),
                std::fs::read(fx.path("t2").join(f)).unwrap(),
                "{f}"
            );
        }
        let objects = read_parquet(&fx.path("t1/objects.parquet"));
        let ids = strs(&objects, "ego_id");
        assert!(ids.iter().any(|i| i == "cv0 -> cv1"), "{objects}");
        assert!(ids.iter().any(|i| i == "cv1"), "{objects}");
        let s = read_csv(&fx.path("t1/summary.csv"));
        let (method, level) = (strs(&s, "method"), strs(&s, "pose_noise"));
        let (f1, single, fused) = (
            f64s(&s, "f1"),
            f64s(&s, "de_single_covis_m"),
            f64s(&s, "de_fused_covis_m"),
        );
        let oracle: Vec<usize> = (0..s.height()).filter(|&k| method[k] == "oracle").collect();
        assert!(
            !oracle.is_empty() && f64s(&s, "n_instances")[0] >= 10.0,
            "{s}"
        );
        for &k in &oracle {
            assert_eq!(f1[k], 1.0, "{s}");
            if level[k] == "none" {
                assert!(fused[k] < single[k], "{s}");
            }
        }
        stale_messages_err_more(&fx, methods, &s);
        let b = |workers: &str, out: &str| {
            fx.coid(&[
                "batch",
                "-q",
                "-c",
                c,
                "--runs",
                "2",
                "--workers",
                workers,
                "-o",
                out,
            ])
        };
        assert_ok(&b("1", "b1"));
        assert_ok(&b("2", "b2"));
        assert_eq!(
            std::fs::read(fx.path("b1/summary.csv")).unwrap(),
            std::fs::read(fx.path("b2/summary.csv")).unwrap()
        );
        assert_ok(&fx.coid(&["render", "-c", c, "-o", "pics", "--instances", "0"]));
        assert!(fx.path("pics/instance-0000.png").is_file());
        let sync = fx.config(
            "s.toml",
            60.0,
            &format!(
                "[connected]\npenetration = 0.3\n{methods}multi_vehicle = \"synchronized\"\n\
                 [v2x]\nmode = \"cpm\"\n"
            ),
        );
        assert_ok(&fx.run(&sync, "sync"));
        let s = read_csv(&fx.path("sync/summary.csv"));
        assert!(f64s(&s, "n_instances")[0] > 50.0, "{s}");
    }

    /// `coid track --sweep`: every setting over every test run, means with
    /// intervals, and the latency plot; the rows at the config's own
    /// values (100 ms, 10 %, 10 Hz) are the same runs, so the same numbers.
    #[test]
    fn a_sweep_covers_latency_loss_and_rate() {
        let fx = Fixture::new();
        let cfg = fx.config(
            "s.toml",
            40.0,
            "[connected]\npenetration = 0.3\n[eval]\ntraffic_seeds = [1, 2]\n",
        );
        let c = cfg.to_str().unwrap();
        assert_ok(&fx.coid(&["track", "-q", "--sweep", "-c", c, "-o", "sw"]));
        let t = read_csv(&fx.path("sw/sweep.csv"));
        assert_eq!(t.height(), 12);
        assert!(f64s(&t, "n_runs").iter().all(|&n| n == 2.0));
        let (factor, value) = (strs(&t, "factor"), f64s(&t, "value"));
        let f1 = f64s(&t, "f1_over_time");
        let at = |f: &str, v: f64| {
            (0..t.height())
                .find(|&k| factor[k] == f && value[k] == v)
                .unwrap()
        };
        assert_eq!(f1[at("latency_ms", 100.0)], f1[at("loss", 0.1)]);
        assert_eq!(f1[at("loss", 0.1)], f1[at("rate_hz", 10.0)]);
        assert!(f1.iter().all(|f| (0.0..=1.0).contains(f)), "{t}");
        for ext in ["png", "svg"] {
            assert!(fx.path(&format!("sw/sweep_latency.{ext}")).is_file());
        }
    }

    /// Named connected vehicles that never appear are refused in one line,
    /// as in `coid run`; a run in which none comes near the junction says
    /// so.
    #[test]
    fn track_refuses_missing_vehicles_and_says_when_none_came() {
        let fx = Fixture::new();
        let named = fx.config("n.toml", 20.0, "");
        let out = fx.coid(&["track", "-q", "-c", named.to_str().unwrap(), "-o", "n"]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(
            err.contains("never appeared") && err.trim().lines().count() == 1,
            "{err}"
        );
        assert!(!fx.path("n").exists());
        let few = fx.config("f.toml", 20.0, "[connected]\npenetration = 0.01\n");
        let out = fx.coid(&["track", "-q", "-c", few.to_str().unwrap(), "-o", "f"]);
        assert_ok(&out);
        assert!(
            stderr(&out).contains("no connected vehicle"),
            "{}",
            stderr(&out)
        );
    }
}

mod regression;
