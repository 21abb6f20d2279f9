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
