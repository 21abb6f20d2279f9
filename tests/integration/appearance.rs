//! `[appearance]` through the binary: the vehicle catalogue and the
//! re-identification descriptor calibrated on the validation runs.

use crate::util::*;

/// A short config with the catalogue and the descriptor at `rank1` and
/// `auroc` (a number or `"free"`), two validation runs and one test run.
fn reid_config(
    fx: &Fixture,
    name: &str,
    descriptor: &str,
    rank1: f64,
    auroc: &str,
) -> std::path::PathBuf {
    fx.config(
        name,
        130.0,
        &format!(
            "[train]\nvalidation_seeds = [125, 126]\n[eval]\ntraffic_seeds = [1]\n\
             [matching]\nmethods = [\"mogm\", \"gps-app-hungarian\", \"oracle\"]\n\
             baselines = \"a-priori\"\n[appearance]\nvehicles = \"catalogue\"\n\
             descriptor = \"{descriptor}\"\nwidth = 32\nrank1 = {rank1}\nauroc = {auroc}\n"
        ),
    )
}

/// The value of `column` in the row of `figure` of a reid.csv.
fn figure(fx: &Fixture, out: &str, figure: &str, column: &str) -> f64 {
    let t = read_csv(&fx.path(&format!("{out}/reid.csv")));
    let row = strs(&t, "figure")
        .iter()
        .position(|f| f == figure)
        .unwrap_or_else(|| panic!("no row {figure}"));
    f64s(&t, column)[row]
}

/// `coid detector` calibrates the descriptor on the validation runs and
/// measures the descriptors the sensor then gives: within 10 % of two
/// different targets (DMGM's rank-1 and AUROC; a rank-1 of 0.7 alone),
/// the measured figures beside the target; a target out of reach is
/// refused with the range the descriptor spans there.
#[test]
fn reid_calibration_holds_for_two_targets() {
    let fx = Fixture::new();
    for (k, (rank1, auroc)) in [(0.39, "0.67"), (0.7, "\"free\"")].into_iter().enumerate() {
        let cfg = reid_config(&fx, &format!("t{k}.toml"), "reid", rank1, auroc);
        let out = format!("det{k}");
        let o = fx.cmd("detector").config(&cfg).out(&out).output();
        assert_ok(&o);
        assert!(
            stderr(&o).contains("calibrated on 2 validation runs"),
            "{}",
            stderr(&o)
        );
        let ratio = figure(&fx, &out, "rank1", "measured_over_target");
        assert!((ratio - 1.0).abs() <= 0.1, "rank-1 {ratio} of {rank1}");
        if auroc != "\"free\"" {
            let ratio = figure(&fx, &out, "auroc", "measured_over_target");
            assert!((ratio - 1.0).abs() <= 0.1, "AUROC {ratio} of {auroc}");
        }
        assert!(figure(&fx, &out, "queries", "measured") > 50.0);
    }
    let cfg = reid_config(&fx, "far.toml", "reid", 0.02, "\"free\"");
    let o = fx.cmd("detector").quiet().config(&cfg).out("far").output();
    assert_refused_unwritten(&o, "cannot reach rank-1 0.02", &fx.path("far"));
}

/// A run with the descriptor gives the same bytes on one and two
/// threads; the descriptor is evidence (MOGM's row moves when it is
/// there), and an export carries it as the nodes' appearance vectors.
#[test]
fn a_run_with_the_descriptor_is_the_same_on_one_and_two_threads() {
    let fx = Fixture::new();
    let cfg = reid_config(&fx, "c.toml", "reid", 0.39, "0.67");
    let plain = reid_config(&fx, "p.toml", "none", 0.39, "0.67");
    for (config, out, threads) in [
        (&cfg, "one", "1"),
        (&cfg, "two", "2"),
        (&plain, "plain", "1"),
    ] {
        let o = fx
            .cmd("run")
            .quiet()
            .config(config)
            .out(out)
            .args(["--threads", threads])
            .output();
        assert_ok(&o);
    }
    let summary = |out: &str| fx.read_text(&format!("{out}/summary.csv"));
    assert!(summary("one") == summary("two"), "1 and 2 threads differ");
    assert!(
        summary("one") != summary("plain"),
        "the descriptor changed nothing"
    );
    let o = fx
        .cmd("export")
        .quiet()
        .config(&cfg)
        .args(["--splits", "test"])
        .out("ex")
        .output();
    assert_ok(&o);
    let o = fx.coid(&["dataset", fx.path("ex").to_str().unwrap()]);
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("32"), "{said}");
}

/// A deep network trained with the descriptor reads it (13 attributes and
/// 16 values a node), the sender's own node included, which carries none
/// (training once stopped there: "appearance vectors of the network's
/// width"); `coid train` trains it once reading the descriptor and once
/// without, and keeps the one the validation runs prefer (its record says
/// which, and with what F1 each; the weights are that candidate's bytes);
/// `coid train --reid-rank1` writes a point of the sweep into
/// `<models_dir>/rank1-<R>` and `coid eval --reid-sweep` evaluates it on
/// the validation and the test runs (the oracle's F1 is 1; the table says
/// what each method made of the descriptor); a point without its models
/// is refused, naming the command that makes them.
#[test]
fn deep_networks_train_on_the_descriptor_and_the_sweep_reads_their_point() {
    let fx = Fixture::new();
    let cfg = fx.config(
        "c.toml",
        130.0,
        &format!(
            "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [125]\nepochs = 1\n\
             methods = [\"ours\"]\n[eval]\ntraffic_seeds = [1]\n[matching]\n\
             methods = [\"ours\", \"mogm\", \"oracle\"]\nmodels_dir = {:?}\n\
             [pose_noise]\nlevels = [\"gps\"]\n[appearance]\nvehicles = \"catalogue\"\n\
             descriptor = \"reid\"\nwidth = 16\n",
            fx.path("models").to_string_lossy()
        ),
    );
    let o = fx
        .cmd("train")
        .quiet()
        .config(&cfg)
        .args(["--reid-rank1", "0.5"])
        .output();
    assert_ok(&o);
    let point = "models/rank1-0.50";
    let reading = fx.read_text(&format!("{point}/candidates/reading-descriptor/ours.toml"));
    assert!(reading.contains("appearance_width = 16"), "{reading}");
    let without = fx.read_text(&format!("{point}/candidates/without-descriptor/ours.toml"));
    assert!(!without.contains("appearance_width"), "{without}");
    let record: toml::Value = toml::from_str(&fx.read_text(&format!("{point}/ours.toml"))).unwrap();
    let choice = &record["descriptor"];
    let f1 = |key: &str| choice[key].as_float().unwrap();
    let reads = choice["reads"].as_bool().unwrap();
    assert_eq!(reads, f1("f1_reading") > f1("f1_without"), "{choice}");
    let chosen = if reads { "reading" } else { "without" };
    let kept = std::fs::read(fx.path(&format!("{point}/ours.bpk"))).unwrap();
    let candidate =
        std::fs::read(fx.path(&format!("{point}/candidates/{chosen}-descriptor/ours.bpk")))
            .unwrap();
    assert!(
        kept == candidate,
        "the kept weights are not the {chosen} candidate's"
    );
    let width = record["architecture"]
        .get("appearance_width")
        .and_then(toml::Value::as_integer);
    assert_eq!(width, reads.then_some(16), "{record}");
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&cfg)
        .args(["--reid-sweep", "0.5"])
        .out("sweep")
        .output();
    assert_ok(&o);
    let t = read_csv(&fx.path("sweep/reid_sweep.csv"));
    let (splits, methods) = (strs(&t, "split"), strs(&t, "method"));
    let f1 = f64s(&t, "f1");
    let oracle: Vec<f64> = (0..t.height())
        .filter(|&k| methods[k] == "oracle")
        .map(|k| f1[k])
        .collect();
    assert_eq!(oracle, vec![1.0, 1.0], "{splits:?} {methods:?}");
    let uses = strs(&t, "descriptor");
    let ours_use = (0..t.height())
        .find(|&k| methods[k] == "ours")
        .map(|k| uses[k].clone());
    let expected = if reads {
        "likelihood weight 1, attributes read"
    } else {
        "likelihood weight 1, attributes left out"
    };
    assert_eq!(ours_use.as_deref(), Some(expected), "{uses:?}");
    let measured = f64s(&t, "rank1_validation")[0];
    assert!((measured / 0.5 - 1.0).abs() <= 0.1, "rank-1 {measured}");
    assert!(fx.path("sweep/reid_sweep.png").exists());
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&cfg)
        .args(["--reid-sweep", "0.7"])
        .out("s2")
        .output();
    assert_refused(&o, "--reid-rank1 0.70");
}

/// Regression: `coid eval --suite` ran a suite config's scenario with its
/// descriptor uncalibrated, which the pipeline refuses; each suite config
/// is calibrated on its own validation runs like the primary one.
#[test]
fn a_suite_config_with_the_descriptor_is_calibrated() {
    let fx = Fixture::new();
    let base = reid_config(&fx, "base.toml", "reid", 0.39, "\"free\"");
    let other = fx.write(
        "other.toml",
        &fx.read_text("base.toml")
            .replace("traffic_seeds = [1]", "traffic_seeds = [2]"),
    );
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&base)
        .arg("--suite")
        .arg(&other)
        .out("ev")
        .output();
    assert_ok(&o);
    let runs = f64s(&read_csv(&fx.path("ev/pooled/table1b.csv")), "n_runs")[0];
    assert_eq!(runs, 2.0);
}
