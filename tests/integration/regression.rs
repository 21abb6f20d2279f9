//! Regression tests, one per defect, named after the issue and finding
//! that reported it (`r31_01_...`: issue 31, finding 1), through the real
//! binary where a user meets the defect. Each failed on the code before
//! its fix.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// A config on the shipped scenario with the two fast methods.
fn fast(fx: &Fixture, name: &str, end_s: f64, extra: &str) -> PathBuf {
    fx.config(
        name,
        end_s,
        &format!("[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n{extra}"),
    )
}

/// `coid batch` of `runs` runs on two workers into `out`, and `extra`.
fn batch(fx: &Fixture, cfg: &Path, runs: &str, out: &str, extra: &[&str]) -> Output {
    let batch = fx.cmd("batch").quiet().config(cfg);
    let batch = batch.args(["--runs", runs, "--workers", "2"]).out(out);
    batch.args(extra).output()
}

/// Whether a staging folder for `name` is in `dir`.
fn staging(dir: &Path, name: &str) -> bool {
    let prefix = format!(".{name}.tmp-");
    names(dir).iter().any(|n| n.starts_with(&prefix))
}

/// Any staging folder in `dir`.
fn any_staging(dir: &Path) -> bool {
    names(dir)
        .iter()
        .any(|n| n.starts_with('.') && n.contains(".tmp-"))
}

fn wait_for_staging(fx: &Fixture, name: &str, child: &mut std::process::Child) {
    let deadline = Instant::now() + Duration::from_secs(60);
    wait_until(deadline, "the command never claimed its folder", || {
        assert!(child.try_wait().unwrap().is_none(), "it ended too soon");
        staging(fx.dir.path(), name)
    });
}

/// 1. A run in which no two connected vehicles share an object is a
///    complete run: the batch exits 0, counts it apart, and a resume does
///    not run it again.
#[test]
fn r31_01_a_batch_with_a_run_without_instances_completes() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "b.toml", 130.0, "");
    let out = batch(&fx, &cfg, "6", "b", &[]);
    assert_ok(&out);
    let empty: Vec<usize> = (0..6)
        .filter(|i| {
            let s = read_csv(&fx.path(&format!("b/runs/run-{i:06}/summary.csv")));
            s.height() > 0 && f64s(&s, "n_instances").iter().all(|&n| n == 0.0)
        })
        .collect();
    assert!(
        !empty.is_empty(),
        "no run without instances: pick other runs"
    );
    let s = read_csv(&fx.path("b/summary.csv"));
    let with = f64s(&s, "n_runs");
    let without = f64s(&s, "n_runs_without_instances");
    for (w, e) in with.iter().zip(&without) {
        assert_eq!((*w + *e, *e), (6.0, empty.len() as f64));
    }
    assert!(f64s(&s, "f1").iter().all(|v| v.is_finite()));
    assert!(
        stderr(&out).contains("without any instance"),
        "{}",
        stderr(&out)
    );
    let first_empty = fx.path(&format!("b/runs/run-{:06}/summary.csv", empty[0]));
    let before = modified(&first_empty);
    let again = batch(&fx, &cfg, "6", "b", &[]);
    assert_ok(&again);
    assert!(stderr(&again).contains("0 runs done"), "{}", stderr(&again));
    assert_eq!(modified(&first_empty), before);
}

/// 2. What appears at `--out` while a run goes on is never replaced (the
///    run's results are kept beside it and it says so), nor is a folder
///    `--force` was to replace that changed meanwhile; of two runs into one
///    `--out`, exactly one writes it.
#[test]
fn r31_02_a_run_never_replaces_what_appeared_at_its_out() {
    let (fx, cfg) = Fixture::with_config(130.0, "");
    let run = |cfg: &Path, out: &str| fx.cmd("run").quiet().config(cfg).out(out);
    let mut child = run(&cfg, "out").spawn();
    wait_for_staging(&fx, "out", &mut child);
    std::fs::create_dir_all(fx.path("out")).unwrap();
    std::fs::write(fx.path("out/mine.txt"), "precious").unwrap();
    let pid = child.id();
    let o = child.wait_with_output().unwrap();
    assert_refused(&o, "appeared while");
    assert_eq!(names(&fx.path("out")), ["mine.txt"]);
    let kept = fx.path(&format!("out.coid-{pid}"));
    assert!(kept.join("summary.csv").is_file(), "the results were lost");
    // --force, and the folder it replaces gets a file meanwhile.
    assert_ok(&fx.run(&cfg, "f"));
    let old = fx.read("f/summary.csv");
    let mut child = run(&cfg, "f").arg("--force").spawn();
    wait_for_staging(&fx, "f", &mut child);
    std::fs::write(fx.path("f/note.txt"), "added").unwrap();
    assert_refused(&child.wait_with_output().unwrap(), "changed while");
    assert!(fx.path("f/note.txt").is_file());
    assert_eq!(fx.read("f/summary.csv"), old);
    // Two runs with different configs into one folder at once.
    let other = fx.config("d.toml", 130.0, "[seeds]\ntraffic = 2\n");
    let (a, b) = (run(&cfg, "both").spawn(), run(&other, "both").spawn());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    assert_ne!(
        a.status.success(),
        b.status.success(),
        "{}{}",
        stderr(&a),
        stderr(&b)
    );
    let lost = if a.status.success() { &b } else { &a };
    let err = stderr(lost);
    assert!(
        err.contains("another coid") || err.contains("appeared while"),
        "{err}"
    );
    assert!(fx.path("both/summary.csv").is_file());
}

/// 3. `--with-matches oracle` writes each instance row once, and the
///    oracle's matches: the export's true pairs at every level.
#[test]
fn r31_03_export_with_matches_oracle_writes_every_row_once() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "e.toml", 60.0, "[eval]\ntraffic_seeds = [1]\n");
    let export = || {
        fx.cmd("export")
            .quiet()
            .config(&cfg)
            .args(["--splits", "test"])
    };
    assert_ok(&export().out("plain").output());
    let with = export().args(["--with-matches", "oracle"]).out("with");
    assert_ok(&with.output());
    for f in ["nodes", "edges", "truth", "true_pairs", "instances"] {
        let file = format!("{f}.parquet");
        let (p, w) = (
            read_parquet(&fx.path("plain").join(&file)).height(),
            read_parquet(&fx.path("with").join(&file)).height(),
        );
        assert_eq!(p, w, "{file}");
    }
    let pairs = read_parquet(&fx.path("with/true_pairs.parquet")).height();
    let oracle = read_parquet(&fx.path("with/matches-oracle.parquet")).height();
    assert!(pairs > 0);
    assert_eq!(oracle, 3 * pairs, "one row per true pair and level");
    let score = fx.cmd("score").quiet().config(&cfg);
    let score = score
        .args(["--matches", "with/true_pairs.parquet"])
        .out("s");
    assert_ok(&score.output());
    let twice = export()
        .args(["--with-matches", "oracle", "oracle"])
        .out("twice");
    assert_refused(&twice.output(), "twice");
}

/// 4. Editing the config while a batch runs changes nothing in it: every
///    run runs from the batch's record; a resume with the edited file is
///    another batch, refused.
#[test]
fn r31_04_a_config_edited_mid_batch_does_not_mix_configurations() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "b.toml", 75.0, "");
    let batch = |out: &str| {
        let batch = fx.cmd("batch").quiet().config(&cfg);
        batch.args(["--runs", "4", "--workers", "1"]).out(out)
    };
    assert_ok(&batch("plain").output());
    let mut child = batch("edited").spawn();
    let first = fx.path("edited/runs/run-000000/summary.csv");
    let deadline = Instant::now() + Duration::from_secs(60);
    wait_until(deadline, "the first run never finished", || {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the batch ended too soon"
        );
        first.is_file()
    });
    let text = fx.read_text("b.toml");
    fx.write(
        "b.toml",
        &format!("{text}[sensor]\nrange_sigma_per_m = 0.3\n"),
    );
    assert_ok(&child.wait_with_output().unwrap());
    assert_eq!(fx.read("edited/summary.csv"), fx.read("plain/summary.csv"));
    assert_refused(&batch("edited").output(), "has changed since");
}

/// 5. A scenario named twice in an evaluation (by `--suite` or `[eval]
///    scenarios`, under any path) is refused: its runs would count twice
///    in the pooled tables.
#[test]
fn r31_05_eval_refuses_a_scenario_named_twice() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "e.toml", 60.0, "[eval]\ntraffic_seeds = [1]\n");
    let eval = |cfg: &Path| fx.cmd("eval").quiet().config(cfg);
    let suite = |other: &Path| eval(&cfg).arg("--suite").arg(other).out("e").output();
    assert_refused(&suite(&cfg), "the same runs");
    std::fs::create_dir_all(fx.path("sub")).unwrap();
    std::fs::copy(&cfg, fx.path("sub/e.toml")).unwrap();
    assert_refused(&suite(Path::new("sub/e.toml")), "the same runs");
    let own = fast(
        &fx,
        "own.toml",
        60.0,
        "[eval]\ntraffic_seeds = [1]\nscenarios = [\"own.toml\"]\n",
    );
    let o = eval(&own).out("e").output();
    assert_refused_unwritten(&o, "the same runs", &fx.path("e"));
}

/// 6. `merge` without every run of the batch fails (unless `--partial`),
///    and writes nothing.
#[test]
fn r31_06_merge_with_a_shard_missing_fails() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "b.toml", 75.0, "");
    assert_ok(&batch(&fx, &cfg, "3", "s1", &["--shard", "1/2"]));
    let merged = fx.coid(&["merge", "s1", "-o", "m"]);
    assert_refused_unwritten(&merged, "missing (1)", &fx.path("m"));
    assert_ok(&fx.coid(&["merge", "s1", "--partial", "-o", "m"]));
    let md = fx.read_text("m/summary.md");
    assert!(md.contains("2 of 3 runs complete"), "{md}");
}

/// 7. `score` refuses matches made from another configuration's export,
///    and says which scored runs the matches file leaves out entirely.
#[test]
fn r31_07_score_checks_the_export_it_scores() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "a.toml", 60.0, "[eval]\ntraffic_seeds = [1, 2]\n");
    let export = fx
        .cmd("export")
        .quiet()
        .config(&cfg)
        .args(["--splits", "test"]);
    let export = export.out("ex").args(["--with-matches", "gps-hungarian"]);
    assert_ok(&export.output());
    let other = fast(
        &fx,
        "b.toml",
        60.0,
        "[eval]\ntraffic_seeds = [1, 2]\n[sensor]\nfalse_positives_per_frame = 0.5\n",
    );
    let score = |cfg: &Path, matches: &str| {
        let score = fx.cmd("score").quiet().config(cfg);
        score.args(["--matches", matches]).out("s")
    };
    let o = score(&other, "ex/matches-gps-hungarian.parquet").output();
    assert_refused(&o, "another configuration");
    // Only the first run's true pairs, as CSV outside the export.
    let pairs = read_parquet(&fx.path("ex/true_pairs.parquet"));
    let runs = f64s(&pairs, "run");
    let keep = runs[0];
    let mut csv = String::from("run,instance,a,b\n");
    for (k, r) in runs.iter().enumerate() {
        if *r == keep {
            let v = |c: &str| f64s(&pairs, c)[k] as u64;
            csv.push_str(&format!(
                "{},{},{},{}\n",
                *r as u64,
                v("instance"),
                v("a"),
                v("b")
            ));
        }
    }
    fx.write("first.csv", &csv);
    assert_refused(&score(&cfg, "first.csv").output(), "pass --export");
    let o = score(&cfg, "first.csv").args(["--export", "ex"]).output();
    assert_ok(&o);
    assert!(
        stderr(&o).contains("names no instance of run(s)"),
        "{}",
        stderr(&o)
    );
}

/// 8. A batch and `merge` take only the runs of their own batch: a
///    standalone run put in place of a batch's run is not that run.
#[test]
fn r31_08_batch_and_merge_take_only_their_own_runs() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "b.toml", 75.0, "");
    assert_ok(&batch(&fx, &cfg, "2", "b", &[]));
    let whole = fx.read("b/summary.csv");
    let run = fx.cmd("run").quiet().arg("--force").config(&cfg);
    let run = run.args(["--traffic-seed", "7"]).out("b/runs/run-000001");
    assert_ok(&run.output());
    assert_refused(&fx.coid(&["merge", "b", "-o", "m"]), "missing (1)");
    let again = batch(&fx, &cfg, "2", "b", &[]);
    assert_ok(&again);
    assert!(stderr(&again).contains("1 run done"), "{}", stderr(&again));
    assert_eq!(fx.read("b/summary.csv"), whole);
}

/// 9. `--force` never replaces a folder coid did not write, whatever
///    files it holds: a user's folder with files named as a run's, or a
///    scenario of their own where `coid scenarios` would write one.
#[test]
fn r31_09_force_never_replaces_a_folder_coid_did_not_write() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "c.toml", 60.0, "");
    std::fs::create_dir_all(fx.path("mine")).unwrap();
    for f in ["summary.csv", "summary.md", "objects.parquet"] {
        fx.write(&format!("mine/{f}"), "mine");
    }
    for cmd in ["run", "eval", "render"] {
        let o = fx.cmd(cmd).quiet().arg("--force").config(&cfg).out("mine");
        assert_refused(&o.output(), "coid did not write it");
    }
    assert_eq!(names(&fx.path("mine")).len(), 3);
    assert_eq!(fx.read_text("mine/summary.csv"), "mine");
    std::fs::create_dir_all(fx.path("fam/s000")).unwrap();
    fx.write("fam/s000/coid.toml", "# my own scenario");
    fx.write("fam/s000/net.net.xml", "<net/>");
    let o = fx
        .cmd("scenarios")
        .quiet()
        .args(["--count", "1", "--force"]);
    assert_refused(&o.out("fam").output(), "coid did not write it");
    assert_eq!(fx.read_text("fam/s000/coid.toml"), "# my own scenario");
}

/// 10. A value that would allocate without bound is refused in one line
///     before anything runs.
#[test]
fn r31_10_mc_samples_beyond_the_bound_are_refused() {
    let fx = Fixture::new();
    for (extra, key) in [
        (
            "[matching]\nmc_samples = 1000000000\n",
            "matching.mc_samples",
        ),
        ("[train]\nmc_samples = 100000\n", "train.mc_samples"),
        (
            "[camera]\nyaw_offsets_deg = [0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16]\n",
            "at most 16",
        ),
    ] {
        let cfg = fx.config("c.toml", 60.0, extra);
        let o = fx.run(&cfg, "r");
        assert_refused(&o, key);
        assert!(!fx.path("r").exists() && !any_staging(fx.dir.path()));
    }
}

/// 11. Thread and worker counts out of range are usage errors, never a
///     panic; a batch says how many workers it really uses.
#[test]
fn r31_11_threads_and_workers_out_of_range_are_refused() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "c.toml", 60.0, "");
    let run = |flag: &str, n: &str| {
        let run = fx.cmd("run").quiet().config(&cfg);
        (format!("run {flag} {n}"), run.args([flag, n]).out("r"))
    };
    let batch = |flag: &str, n: &str| {
        let batch = fx.cmd("batch").quiet().config(&cfg).args(["--runs", "1"]);
        (format!("batch {flag} {n}"), batch.args([flag, n]).out("b"))
    };
    for (what, cmd) in [
        run("--threads", "100000"),
        run("--threads", "0"),
        batch("--workers", "0"),
        batch("--workers", "100000"),
        batch("--threads", "100000"),
    ] {
        let o = cmd.output();
        assert_eq!(o.status.code(), Some(2), "{what}: {}", stderr(&o));
        assert!(stderr(&o).contains("is not in 1..=1024"), "{}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"));
    }
    assert!(!fx.path("r").exists() && !fx.path("b").exists());
    assert!(!any_staging(fx.dir.path()));
    let o = batch("--workers", "8").1.output();
    assert_ok(&o);
    assert!(stderr(&o).contains("on 1 worker "), "{}", stderr(&o));
}

/// 12. Temporary files go: a run leaves nothing in the temporary folder;
///     Ctrl-C removes the run's staging folder and its capture of SUMO's
///     messages; what a process killed outright leaves is removed by the
///     next coid (also for another `--out` in the same folder).
#[test]
fn r31_12_no_temporary_files_are_left_behind() {
    let fx = Fixture::new();
    let tmp = fx.path("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let cfg = fast(&fx, "c.toml", 130.0, "[connected]\npenetration = 0.3\n");
    let run = |cfg: &Path, out: &str| {
        fx.cmd("run")
            .quiet()
            .config(cfg)
            .out(out)
            .env("TMPDIR", &tmp)
    };
    assert!(run(&cfg, "a").command().status().unwrap().success());
    assert!(names(&tmp).is_empty(), "{:?}", names(&tmp));
    for (signal, code) in [("-INT", Some(130)), ("-TERM", Some(143)), ("-KILL", None)] {
        let mut child = run(&cfg, "b").command().spawn().unwrap();
        wait_for_staging(&fx, "b", &mut child);
        send_signal(&child, signal);
        assert_eq!(child.wait().unwrap().code(), code, "{signal}");
        assert!(!fx.path("b").exists());
        if code.is_some() {
            assert!(
                !any_staging(fx.dir.path()),
                "{signal}: {:?}",
                names(fx.dir.path())
            );
            assert!(names(&tmp).is_empty(), "{signal}: {:?}", names(&tmp));
        }
    }
    // Killed outright: its staging folder stays until the next coid in
    // the same folder, whatever its --out.
    assert!(staging(fx.dir.path(), "b"));
    let quick = fast(&fx, "q.toml", 20.0, "[connected]\npenetration = 0.3\n");
    assert_ok(&run(&quick, "other").output());
    assert!(!any_staging(fx.dir.path()), "{:?}", names(fx.dir.path()));
    assert!(names(&tmp).is_empty(), "{:?}", names(&tmp));
}

/// 13. A list that names something twice is refused (it was merged
///     silently; two cameras in one direction doubled every detection).
#[test]
fn r31_13_repeated_list_entries_are_refused() {
    let fx = Fixture::new();
    for (extra, key) in [
        (
            "[pose_noise]\nlevels = [\"gps\", \"gps\"]\n",
            "pose_noise.levels: lists 'gps' twice",
        ),
        (
            "[fusion]\nvariants = [\"paper\", \"paper\"]\n",
            "fusion.variants",
        ),
        (
            "[matching]\nmethods = [\"rgm\", \"rgm\"]\n",
            "matching.methods",
        ),
        ("[train]\nmethods = [\"ours\", \"ours\"]\n", "train.methods"),
        (
            "[camera]\nyaw_offsets_deg = [0.0, 360.0]\n",
            "the same camera",
        ),
    ] {
        let cfg = fx.config("c.toml", 60.0, extra);
        assert_refused(&fx.run(&cfg, "r"), key);
    }
}

/// 14. Messages say what is wrong.
#[test]
fn r31_14_messages_say_what_is_wrong() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "c.toml", 60.0, "");
    // A huge number is written as a number, not 300 digits.
    let huge = fx.config("h.toml", 20.0, "[sensor]\ncolour_sigma = -1e300\n");
    assert_refused(&fx.run(&huge, "r"), "got -1e300");
    // An --out that is a file, or a symbolic link to nothing: before SUMO.
    fx.write("afile", "x");
    assert_refused(&fx.run(&cfg, "afile"), "it is a file");
    std::os::unix::fs::symlink(fx.path("nowhere"), fx.path("dangling")).unwrap();
    let started = Instant::now();
    assert_refused(&fx.run(&cfg, "dangling"), "which does not exist");
    assert!(started.elapsed() < Duration::from_secs(10));
    // A folder of another command's results is named as such.
    assert_ok(&fx.run(&cfg, "r"));
    let o = fx.cmd("eval").quiet().arg("--force").config(&cfg).out("r");
    assert_refused(&o.output(), "it holds a run's results (coid run)");
    // A test seed in the training seeds, set in [eval]: reported there.
    let overlap = fx.config("o.toml", 20.0, "[eval]\ntraffic_seeds = [101]\n");
    assert_refused(
        &fx.run(&overlap, "x"),
        "eval.traffic_seeds: seed 101 is in both",
    );
    // A sumocfg that is a folder.
    let folder = fx.write("d.toml", &scenario_toml(&repo().join("sumo_nets"), "C"));
    assert_refused(
        &fx.run(&folder, "x"),
        "is a folder, not a SUMO configuration",
    );
    // An --out name near the file system's limit (255 bytes) works.
    let long = "l".repeat(250);
    assert_ok(&fx.run(&cfg, &long));
    assert!(fx.path(&long).join("summary.csv").is_file());
}

/// 14, continued: matches files and `coid track`.
#[test]
fn r31_14_matches_files_and_track_lines_say_what_is_wrong() {
    let fx = Fixture::new();
    let cfg = fast(&fx, "e.toml", 60.0, "[eval]\ntraffic_seeds = [1]\n");
    let export = fx
        .cmd("export")
        .quiet()
        .config(&cfg)
        .args(["--splits", "test"]);
    assert_ok(&export.out("ex").output());
    let pairs = read_parquet(&fx.path("ex/true_pairs.parquet"));
    let v = |col: &str| f64s(&pairs, col)[0] as u64;
    let row = format!("{},{},{},{}", v("run"), v("instance"), v("a"), v("b"));
    // An uncertainty beyond 1 bit.
    fx.write(
        "ex/bad.csv",
        &format!("run,instance,a,b,uncertainty\n{row},5.0\n"),
    );
    let score = |m: &str| {
        let score = fx.cmd("score").quiet().config(&cfg);
        score.args(["--matches", m]).out("s").output()
    };
    assert_refused(&score("ex/bad.csv"), "uncertainty 5 is not in [0, 1]");
    // A CSV file named in capitals is read as CSV.
    fx.write("ex/OK.CSV", &format!("run,instance,a,b\n{row}\n"));
    assert_ok(&score("ex/OK.CSV"));
    // Every message lost: no NaN in the one-line summary.
    let lossy = fx.config("t.toml", 60.0, "[v2x.channel]\nloss_probability = 1.0\n");
    let o = fx.cmd("track").quiet().config(&lossy).out("t").output();
    assert_ok(&o);
    assert!(!stderr(&o).contains("NaN"), "{}", stderr(&o));
    assert!(stderr(&o).contains("no pair to score"), "{}", stderr(&o));
}

/// Issue 33, found when `coid run`'s default seeds moved: the install
/// folder's name covered the shipped models and scenario but not the
/// compiled defaults, so a build with other defaults read the defaults an
/// earlier build had written there. A folder whose defaults are not this
/// binary's is written again: `coid run` without a config runs at this
/// binary's default seeds.
#[test]
fn r33_stale_defaults_in_the_install_folder_are_never_read() {
    let fx = Fixture::new();
    assert_ok(&fx.cmd("run").quiet().out("a").output());
    let home = fx.path(".coid-home");
    let install = std::fs::read_dir(&home)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("install-")
        })
        .expect("an install folder");
    let defaults = install.join("configs/default.toml");
    let text = std::fs::read_to_string(&defaults).unwrap();
    let stale = text
        .replace("traffic = 1001", "traffic = 1")
        .replace("sensor = 1001", "sensor = 1");
    assert_ne!(stale, text, "the defaults name seeds 1001");
    std::fs::write(&defaults, stale).unwrap();
    assert_ok(&fx.cmd("run").quiet().out("b").output());
    let md = fx.read_text("b/summary.md");
    assert!(md.contains("seeds: traffic 1001, sensor 1001"), "{md}");
}
