//! Regression tests of issue 49 (a hostile newcomer's test of detector
//! profiles, rigs, GNSS, CPMs, scenarios and score), one per finding,
//! named `r49_NN_...` after it, through the real binary. Each failed on
//! the code before its fix.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// The fast methods, as most findings need no network.
const FAST: &str = "[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n";

/// One training, one validation and one test run: an export of every
/// split stays short.
const ONE_RUN_EACH: &str =
    "[train]\ntraffic_seeds = [101]\nvalidation_seeds = [125]\n[eval]\ntraffic_seeds = [1]\n";

/// A 60 s config of `extra` on the shipped scenario.
fn config(fx: &Fixture, name: &str, extra: &str) -> PathBuf {
    fx.config(name, 60.0, extra)
}

/// 1. A camera error of 10 km per detection: `ours` runs and reports
///    finite numbers (it panicked on a NaN probability).
#[test]
fn r49_01_a_camera_error_of_ten_kilometres_runs_ours_without_a_panic() {
    let fx = Fixture::new();
    let cfg = config(
        &fx,
        "c.toml",
        "[matching]\nmethods = [\"ours\"]\n[detector]\nprofile = \"camera\"\n\
         [detector.camera]\nmean_error_m = [1e4, 2.0, 3.0]\n",
    );
    let o = fx.cmd("run").quiet().config(&cfg).args(["--threads", "1"]);
    let o = o.out("out").output();
    assert_ok(&o);
    assert!(!stderr(&o).contains("internal error"), "{}", stderr(&o));
    let s = read_csv(&fx.path("out/summary.csv"));
    for col in ["precision", "recall", "f1"] {
        assert!(f64s(&s, col).iter().all(|v| v.is_finite()), "{col}");
    }
}

/// 2. Every detector, rig and GNSS value is checked for a finite number
///    in range, and refused naming its key.
#[test]
fn r49_02_non_finite_detector_rig_and_gnss_values_are_refused_by_name() {
    let rig = |yaw: &str| {
        format!(
            "[detector]\nrig_by_type = {{ cv = \"r\" }}\n[detector.rigs.r]\nprofile = \"camera\"\n\
             sensors = [{{ yaw_deg = {yaw}, fov_deg = 70, range_m = 70, height_m = 1.5, \
             mount = \"roof\" }}]\n"
        )
    };
    let cases = [
        (
            "[detector.camera]\ntail_dof = inf\n".to_owned(),
            "detector.camera.tail_dof",
        ),
        (
            "[detector.camera]\nyaw_offsets_deg = [nan]\n".to_owned(),
            "detector.camera.yaw_offsets_deg",
        ),
        (
            "[detector.camera]\ndepth_to_lateral = 1e200\n".to_owned(),
            "detector.camera.depth_to_lateral",
        ),
        (
            "[detector.lidar]\ndepth_bias_per_m = 1e300\n".to_owned(),
            "detector.lidar.depth_bias_per_m",
        ),
        (
            "[detector.lidar]\nbin_edges_m = [30.0, 50.0, inf]\n".to_owned(),
            "detector.lidar.bin_edges_m",
        ),
        (rig("nan"), "yaw_deg"),
        (rig("inf"), "yaw_deg"),
        (rig("1e300"), "yaw_deg"),
        (
            "[v2x]\ngnss_heading_speed_sigma_mps = 1e308\n".to_owned(),
            "v2x.gnss_heading_speed_sigma_mps",
        ),
        (
            "[v2x]\ngnss_correlation_s = inf\n".to_owned(),
            "v2x.gnss_correlation_s",
        ),
        (
            "[pose_noise.gps]\nposition_sigma_m = 1e308\n".to_owned(),
            "pose_noise",
        ),
    ];
    let fx = Fixture::new();
    for (k, (extra, key)) in cases.iter().enumerate() {
        let cfg = config(&fx, &format!("c{k}.toml"), extra);
        for command in ["detector", "run"] {
            let o = fx.cmd(command).quiet().config(&cfg).out("out").output();
            assert_refused_unwritten(&o, key, &fx.path("out"));
        }
    }
}

/// 3. A NaN in a row of the class confusion is refused (a sum check
///    cannot see it).
#[test]
fn r49_03_a_nan_in_a_class_confusion_row_is_refused() {
    let mut rows: Vec<String> = (0..7)
        .map(|r| {
            let v: Vec<&str> = (0..7).map(|c| if r == c { "1.0" } else { "0.0" }).collect();
            format!("[{}]", v.join(", "))
        })
        .collect();
    rows[0] = "[nan, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]".into();
    let extra = format!(
        "[detector.camera]\nclass_confusion = [{}]\n",
        rows.join(", ")
    );
    let (fx, cfg) = Fixture::with_config(60.0, &extra);
    let o = fx.run(&cfg, "out");
    assert_refused_unwritten(&o, "detector.camera.class_confusion", &fx.path("out"));
}

/// 4. `by_type` naming a type no road user has changes nothing, and the
///    run says so with the types it had; an empty type is refused.
#[test]
fn r49_04_by_type_naming_a_missing_vehicle_type_is_said() {
    let fx = Fixture::new();
    let cfg = config(
        &fx,
        "c.toml",
        &format!("{FAST}[detector]\nby_type = {{ cv_lidar = \"lidar\" }}\n"),
    );
    let o = fx.run(&cfg, "out");
    assert_ok(&o);
    let err = stderr(&o);
    assert!(
        err.contains("'cv_lidar'") && err.contains("changed nothing"),
        "{err}"
    );
    assert!(
        err.contains("cv,") || err.contains("cv)"),
        "the run's types: {err}"
    );
    // The documented example names the default scenario's type: no
    // warning, and it changes the run.
    let cv = config(
        &fx,
        "cv.toml",
        &format!("{FAST}[detector]\nby_type = {{ cv = \"lidar\" }}\n"),
    );
    let o = fx.run(&cv, "cv");
    assert_ok(&o);
    assert!(!stderr(&o).contains("changed nothing"), "{}", stderr(&o));
    assert_ne!(fx.read("cv/summary.csv"), fx.read("out/summary.csv"));
    let empty = config(
        &fx,
        "e.toml",
        "[detector]\nby_type = { \"\" = \"lidar\" }\n",
    );
    assert_refused_unwritten(&fx.run(&empty, "e"), "detector.by_type", &fx.path("e"));
}

/// 5. The documented `coid score --matches true_pairs.parquet` on a
///    default export (every split) scores the test runs and reproduces
///    the oracle's rows; the rows of the other splits are left out, and
///    said.
#[test]
fn r49_05_score_of_a_default_export_reproduces_the_oracle() {
    let fx = Fixture::new();
    let cfg = config(&fx, "c.toml", &format!("{FAST}{ONE_RUN_EACH}"));
    assert_ok(&fx.cmd("export").quiet().config(&cfg).out("ex").output());
    let o = fx
        .cmd("score")
        .quiet()
        .config(&cfg)
        .args(["--matches", "ex/true_pairs.parquet"])
        .out("s")
        .output();
    assert_ok(&o);
    assert!(stderr(&o).contains("left out"), "{}", stderr(&o));
    let s = read_csv(&fx.path("s/table1b.csv"));
    let (m, l) = (strs(&s, "method"), strs(&s, "pose_noise"));
    for level in ["none", "rtk", "gps"] {
        let row = |method: &str| {
            (0..m.len())
                .find(|&k| m[k] == method && l[k] == level)
                .unwrap_or_else(|| panic!("no {method} row at {level}"))
        };
        let (e, o) = (row("external"), row("oracle"));
        for col in ["precision", "recall", "f1"] {
            assert_eq!(f64s(&s, col)[e], f64s(&s, col)[o], "{col} at {level}");
        }
    }
}

/// `coid export` into `ex` of the one test run (seed 1) of a 60 s config
/// of the fast methods and `extra`.
fn export_one_test_run(fx: &Fixture, extra: &str) {
    let cfg = config(
        fx,
        "c.toml",
        &format!("{FAST}[eval]\ntraffic_seeds = [1]\n{extra}"),
    );
    let export = fx.cmd("export").quiet().config(&cfg);
    assert_ok(&export.args(["--splits", "test"]).out("ex").output());
}

/// 6. With `gnss_heading_speed_sigma_mps`, the heading accuracy each
///    receiver claims is the one its error is drawn with: the level's and
///    the course over ground's at its speed in quadrature, per vehicle
///    (the export's claim was the level's for both).
#[test]
fn r49_06_the_claimed_heading_accuracy_is_the_one_drawn() {
    let fx = Fixture::new();
    export_one_test_run(&fx, "[v2x]\ngnss_heading_speed_sigma_mps = 1.0\n");
    // Each side's speed: its own node's (the true speed).
    let nodes = read_parquet(&fx.path("ex/nodes.parquet"));
    let sender = nodes.column("sender").unwrap().bool().unwrap().clone();
    let (inst, side, speed) = (
        f64s(&nodes, "instance"),
        f64s(&nodes, "side"),
        f64s(&nodes, "speed_mps"),
    );
    let mut speeds = std::collections::BTreeMap::new();
    for (k, s) in sender.iter().enumerate() {
        if s == Some(true) {
            speeds.insert((inst[k] as u64, side[k] as u64), speed[k]);
        }
    }
    let rows = read_parquet(&fx.path("ex/instances.parquet"));
    let levels = strs(&rows, "pose_noise");
    let instance = f64s(&rows, "instance");
    let claims = [
        f64s(&rows, "first_heading_sigma_rad"),
        f64s(&rows, "second_heading_sigma_rad"),
    ];
    let mut checked = 0;
    for k in 0..rows.height() {
        let level: f64 = match levels[k].as_str() {
            "gps" | "rtk" => 0.2f64.to_radians(),
            _ => continue,
        };
        for (s, claim) in claims.iter().enumerate() {
            let v = speeds[&(instance[k] as u64, s as u64)];
            let drawn = level.hypot(1.0 / v.max(0.4));
            assert!(
                (claim[k] - drawn).abs() < 1e-12,
                "claimed {} against {drawn}",
                claim[k]
            );
            checked += 1;
        }
    }
    assert!(checked > 0, "no instance");
}

/// 7. SIGINT while a family is written leaves nothing behind, and the
///    same command then writes it.
#[test]
fn r49_07_an_interrupted_family_leaves_nothing_and_is_written_again() {
    let fx = Fixture::new();
    let generate = || {
        fx.cmd("scenarios")
            .quiet()
            .args(["--count", "6"])
            .out("fam")
    };
    let mut child = generate().spawn();
    let deadline = Instant::now() + Duration::from_secs(60);
    wait_until(deadline, "the family was never staged", || {
        names(fx.dir.path())
            .iter()
            .any(|n| n.starts_with(".fam.tmp-"))
    });
    // Into the first scenario's netconvert, not past the family.
    std::thread::sleep(Duration::from_millis(300));
    send_signal(&child, "-INT");
    let o = child.wait().unwrap();
    assert!(!o.success(), "it finished before the signal");
    let left: Vec<String> = names(fx.dir.path())
        .into_iter()
        .filter(|n| n.contains("fam"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    assert_ok(&generate().output());
    assert!(fx.path("fam/README.md").is_file());
    assert!(fx.path("fam/s005/net.net.xml").is_file());
}

/// 8. A coasting gap shorter than a step drops every track before its
///    second hit: refused, naming the key the user set.
#[test]
fn r49_08_a_coasting_gap_shorter_than_a_step_is_refused() {
    let (fx, cfg) = Fixture::with_config(60.0, "[v2x]\nstep_length_s = 1.0\n");
    let o = fx.cmd("track").quiet().config(&cfg).out("out").output();
    assert_refused_unwritten(&o, "v2x.step_length_s", &fx.path("out"));
    assert!(stderr(&o).contains("second hit"), "{}", stderr(&o));
    let (fx, cfg) = Fixture::with_config(60.0, "[v2x.tracker]\nmax_coast_s = 0.05\n");
    let o = fx.cmd("track").quiet().config(&cfg).out("out").output();
    assert_refused_unwritten(&o, "v2x.tracker.max_coast_s", &fx.path("out"));
}

/// The test split of a config with two test runs exported to `ex` with
/// GPS-Hungarian's matches.
fn exported(fx: &Fixture, extra: &str) -> PathBuf {
    let cfg = config(
        fx,
        "c.toml",
        &format!("{FAST}[eval]\ntraffic_seeds = [1, 2]\n{extra}"),
    );
    let export = fx.cmd("export").quiet().config(&cfg);
    let export = export.args(["--splits", "test", "--with-matches", "gps-hungarian"]);
    assert_ok(&export.out("ex").output());
    cfg
}

/// `coid score` of `matches` from the export `ex`.
fn score(fx: &Fixture, cfg: &Path, matches: &str, out: &str) -> Output {
    let score = fx.cmd("score").quiet().config(cfg);
    let score = score.args(["--matches", matches, "--export", "ex"]);
    score.out(out).output()
}

/// The first test run's index in `ex`.
fn first_run(fx: &Fixture) -> u64 {
    f64s(&read_parquet(&fx.path("ex/runs.parquet")), "run")[0] as u64
}

/// 9. A Parquet matches file of any integer type is read, and scores as
///    the same matches in 64-bit integers.
#[test]
fn r49_09_matches_of_small_integer_types_are_read() {
    use polars::prelude::*;
    let fx = Fixture::new();
    let cfg = exported(&fx, "");
    assert_ok(&score(
        &fx,
        &cfg,
        "ex/matches-gps-hungarian.parquet",
        "wide",
    ));
    let mut df = read_parquet(&fx.path("ex/matches-gps-hungarian.parquet"));
    for (col, to) in [
        ("run", DataType::UInt8),
        ("instance", DataType::UInt16),
        ("a", DataType::Int8),
        ("b", DataType::Int16),
    ] {
        let c = df.column(col).unwrap().cast(&to).unwrap();
        df.with_column(c).unwrap();
    }
    let path = fx.path("ex/narrow.parquet");
    ParquetWriter::new(std::fs::File::create(&path).unwrap())
        .finish(&mut df)
        .unwrap();
    assert_ok(&score(&fx, &cfg, "ex/narrow.parquet", "narrow"));
    assert_eq!(fx.read("narrow/table1b.csv"), fx.read("wide/table1b.csv"));
}

/// A 60 s run in `cpm` mode with `channel` as `[v2x.channel]`.
fn cpm(fx: &Fixture, name: &str, channel: &str) -> PathBuf {
    config(
        fx,
        name,
        &format!("{FAST}[v2x]\nmode = \"cpm\"\n[v2x.channel]\n{channel}"),
    )
}

/// 10. A cpm run without an instance because the channel delivers
///     nothing blames the channel, not the connected vehicles.
#[test]
fn r49_10_a_cpm_run_without_deliveries_blames_the_channel() {
    let fx = Fixture::new();
    for (name, channel, expect) in [
        ("lost", "loss_probability = 1.0\n", "loses every message"),
        ("late", "latency_s = 1000.0\n", "latency_s"),
    ] {
        let cfg = cpm(&fx, &format!("{name}.toml"), channel);
        let o = fx.run(&cfg, name);
        assert_ok(&o);
        let err = stderr(&o);
        assert!(err.contains("no instance") && err.contains(expect), "{err}");
        assert!(!err.contains("[connected]"), "{err}");
    }
}

/// 11. Messages still on their way when the run ends are counted apart,
///     not as delivered with their latency.
#[test]
fn r49_11_messages_in_flight_at_the_end_are_not_delivered() {
    let fx = Fixture::new();
    let cfg = cpm(
        &fx,
        "c.toml",
        "latency_s = 1000.0\nloss_probability = 0.0\n",
    );
    let o = fx.cmd("track").quiet().config(&cfg).out("out").output();
    assert_ok(&o);
    let t = read_csv(&fx.path("out/tracking.csv"));
    assert!(f64s(&t, "delivered").iter().all(|&d| d == 0.0));
    let in_flight: f64 = f64s(&t, "in_flight_at_end").iter().sum();
    assert!(in_flight > 0.0, "nothing was sent");
    assert!(f64s(&t, "mean_latency_s").iter().all(|l| l.is_nan()));
    assert!(stderr(&o).contains("still on their way"), "{}", stderr(&o));
}

/// 12. In a cpm export, a message side's sender node carries the box of
///     its self-report (heading 0 in its body frame, its speed), as the
///     schema says.
#[test]
fn r49_12_a_message_sides_sender_node_carries_its_box() {
    let fx = Fixture::new();
    export_one_test_run(&fx, "[v2x]\nmode = \"cpm\"\n");
    let nodes = read_parquet(&fx.path("ex/nodes.parquet"));
    let (heading, speed) = (f64s(&nodes, "heading_rad"), f64s(&nodes, "speed_mps"));
    let sender = nodes.column("sender").unwrap().bool().unwrap().clone();
    let mut senders = 0;
    for (k, s) in sender.iter().enumerate() {
        if s == Some(true) {
            senders += 1;
            assert_eq!(heading[k], 0.0, "node row {k}");
            assert!(speed[k].is_finite() && speed[k] >= 0.0, "node row {k}");
        }
    }
    assert!(senders > 0, "no sender node");
}

/// 13. A speed error beyond any detector's is refused (it overflowed the
///     reported speed).
#[test]
fn r49_13_a_speed_sigma_that_overflows_is_refused() {
    let fx = Fixture::new();
    for (k, (extra, key)) in [
        (
            "[sensor]\nspeed_sigma_mps = 1e308\n",
            "sensor.speed_sigma_mps",
        ),
        (
            "[detector.camera]\nspeed_sigma_mps = 1e308\n",
            "detector.camera.speed_sigma_mps",
        ),
        (
            "[sensor]\nheading_sigma_deg = 1e308\n",
            "sensor.heading_sigma_deg",
        ),
    ]
    .iter()
    .enumerate()
    {
        let cfg = config(&fx, &format!("c{k}.toml"), extra);
        assert_refused_unwritten(&fx.run(&cfg, "out"), key, &fx.path("out"));
    }
}

/// 14. A matches CSV naming a column twice is refused.
#[test]
fn r49_14_a_matches_csv_naming_a_column_twice_is_refused() {
    let fx = Fixture::new();
    let cfg = exported(&fx, "");
    let run = first_run(&fx);
    fx.write("twice.csv", &format!("run,instance,a,b,b\n{run},0,0,0,1\n"));
    let o = score(&fx, &cfg, "twice.csv", "s");
    assert_refused_unwritten(&o, "names column 'b' twice", &fx.path("s"));
}

/// 15. An empty cell of an optional column is refused, not read as its
///     default.
#[test]
fn r49_15_an_empty_probability_cell_is_refused() {
    let fx = Fixture::new();
    let cfg = exported(&fx, "");
    let run = first_run(&fx);
    fx.write(
        "empty.csv",
        &format!("run,instance,a,b,probability\n{run},0,0,0,0.9\n{run},0,1,1,\n"),
    );
    let o = score(&fx, &cfg, "empty.csv", "s");
    assert_refused_unwritten(&o, "column 'probability' is empty in row 2", &fx.path("s"));
    fx.write(
        "level.csv",
        &format!("run,instance,pose_noise,a,b\n{run},0,gps,0,0\n{run},0,,1,1\n"),
    );
    let o = score(&fx, &cfg, "level.csv", "s");
    assert_refused_unwritten(&o, "column 'pose_noise' is empty in row 2", &fx.path("s"));
}

/// 16. `score` refuses an export written by a newer coid, and an export
///     that does not hold the runs it scores.
#[test]
fn r49_16_score_refuses_a_newer_export_and_one_without_the_scored_runs() {
    use polars::prelude::*;
    let fx = Fixture::new();
    let cfg = exported(&fx, "[train]\ntraffic_seeds = [101]\n");
    let matches = "ex/matches-gps-hungarian.parquet";
    // The same export as a newer coid would write it.
    std::fs::create_dir_all(fx.path("new")).unwrap();
    for f in ["runs.parquet", "matches-gps-hungarian.parquet"] {
        std::fs::copy(fx.path("ex").join(f), fx.path("new").join(f)).unwrap();
    }
    let path = fx.path("new/runs.parquet");
    let mut runs = read_parquet(&path);
    let n = runs.height();
    runs.with_column(Column::new("schema_version".into(), vec![99u64; n]))
        .unwrap();
    ParquetWriter::new(std::fs::File::create(&path).unwrap())
        .finish(&mut runs)
        .unwrap();
    let o = fx.cmd("score").quiet().config(&cfg);
    let o = o.args(["--matches", "new/matches-gps-hungarian.parquet"]);
    assert_refused_unwritten(&o.out("s").output(), "newer coid", &fx.path("s"));
    // An export of the training run only, for matches of the test runs.
    let train = fx
        .cmd("export")
        .quiet()
        .config(&cfg)
        .args(["--splits", "train"]);
    assert_ok(&train.out("train").output());
    let o = fx.cmd("score").quiet().config(&cfg);
    let o = o.args(["--matches", matches, "--export", "train"]).out("s");
    assert_refused_unwritten(&o.output(), "does not hold the 2 test runs", &fx.path("s"));
}

/// 17. Extending a family keeps every scenario and command in its README;
///     a family is of one seed.
#[test]
fn r49_17_extending_a_family_keeps_every_scenario_in_its_readme() {
    let fx = Fixture::new();
    let generate = |args: &[&str]| fx.cmd("scenarios").quiet().args(args).out("fam").output();
    assert_ok(&generate(&["--count", "2", "--seed", "4"]));
    assert_ok(&generate(&[
        "--count", "1", "--seed", "4", "--first", "2", "--force",
    ]));
    let readme = fx.read_text("fam/README.md");
    for s in ["s000", "s001", "s002"] {
        assert!(
            readme.contains(&format!("- {s}: ")),
            "{s} missing: {readme}"
        );
    }
    assert!(readme.contains("--first 0`, then `coid scenarios --count 1 --seed 4 --first 2`"));
    assert_refused(
        &generate(&["--count", "1", "--seed", "5", "--first", "3"]),
        "family seed 4",
    );
    assert_refused(
        &generate(&["--count", "1", "--seed", "4", "--first", "1"]),
        "--force",
    );
    assert_eq!(fx.read_text("fam/README.md"), readme);
    // Replacing a scenario with --force keeps the family whole.
    assert_ok(&generate(&[
        "--count", "1", "--seed", "4", "--first", "1", "--force",
    ]));
    assert!(fx.read_text("fam/README.md").contains("- s001: "));
    assert_eq!(
        names(&fx.path("fam"))
            .iter()
            .filter(|n| n.starts_with('s'))
            .count(),
        3
    );
}

/// 18. `coid detector` says which fleet settings it sets aside to measure
///     one profile, and a configuration with no sensing is refused.
#[test]
fn r49_18_the_detector_report_says_what_it_sets_aside_and_needs_sensings() {
    let fx = Fixture::new();
    let one = "[train]\nvalidation_seeds = [125]\n";
    let cfg = config(
        &fx,
        "mix.toml",
        &format!("{one}[detector]\nprofile = \"camera\"\nmix = {{ camera = 0.5, lidar = 0.5 }}\n"),
    );
    let o = fx.cmd("detector").quiet().config(&cfg).out("mix").output();
    assert_ok(&o);
    assert!(stderr(&o).contains("mix set aside"), "{}", stderr(&o));
    let none = config(&fx, "none.toml", &format!("radius_m = 0.001\n{one}"));
    let o = fx
        .cmd("detector")
        .quiet()
        .config(&none)
        .out("none")
        .output();
    assert_refused_unwritten(&o, "nothing to measure", &fx.path("none"));
}

/// 19. A count of one is singular.
#[test]
fn r49_19_counts_of_one_are_singular() {
    let fx = Fixture::new();
    let cfg = config(
        &fx,
        "c.toml",
        "[matching]\nmethods = [\"oracle\"]\n[eval]\ntraffic_seeds = [1]\n",
    );
    let o = fx
        .cmd("export")
        .quiet()
        .config(&cfg)
        .args(["--splits", "test"]);
    let o = o.out("ex").output();
    assert_ok(&o);
    assert!(stderr(&o).contains("exported 1 run ("), "{}", stderr(&o));
    let o = fx.cmd("eval").quiet().config(&cfg).out("ev").output();
    assert_ok(&o);
    assert!(
        stderr(&o).contains("evaluated 1 method on 1 test run of 1 scenario"),
        "{}",
        stderr(&o)
    );
    let o = fx
        .cmd("scenarios")
        .quiet()
        .args(["--count", "1"])
        .out("fam")
        .output();
    assert_ok(&o);
    assert!(stderr(&o).contains("1 scenario (seed"), "{}", stderr(&o));
}

/// 20. `--force` on a run folder whose summary.md was edited says what
///     changed, not that it is no run's results.
#[test]
fn r49_20_force_on_an_edited_run_folder_says_what_changed() {
    let fx = Fixture::new();
    let cfg = config(&fx, "c.toml", FAST);
    assert_ok(&fx.run(&cfg, "out"));
    let mut md = fx.read_text("out/summary.md");
    md.push_str("\nmy note\n");
    fx.write("out/summary.md", &md);
    let o = fx
        .cmd("run")
        .quiet()
        .config(&cfg)
        .out("out")
        .arg("--force")
        .output();
    assert_refused(&o, "summary.md changed since coid wrote it");
    assert!(!stderr(&o).contains("it is not"), "{}", stderr(&o));
    assert_eq!(fx.read_text("out/summary.md"), md);
}
