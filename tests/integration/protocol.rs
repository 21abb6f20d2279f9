//! The study protocol as a user meets it: a minimal config of their own, a
//! method that identifies nothing.

use crate::util::*;

/// A user's own config in their own folder, holding only `[scenario]`
/// and `[connected]` (docs/configuration.md's example), runs with the shipped
/// weights and their validated lambdas.
#[test]
fn a_minimal_user_config_runs_with_the_shipped_models() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("mine")).unwrap();
    let cfg = fx.config(
        "mine/study.toml",
        80.0,
        "[connected]\nids = [\"cv0\", \"cv1\"]\n",
    );
    assert_ok(&fx.run(&cfg, "mine/out"));
    let summary = read_csv(&fx.path("mine/out/summary.csv"));
    let methods = strs(&summary, "method");
    for m in ["coid", "dgmc", "ours", "gps-app-hungarian", "oracle"] {
        assert!(methods.iter().any(|x| x == m), "{m} missing");
    }
}

/// With lambda 0 the thresholding methods keep no pair: their
/// precision is undefined (not 1), recall and F1 are 0.
#[test]
fn a_method_that_identifies_nothing_has_undefined_precision() {
    let (fx, cfg) = Fixture::with_config(
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
    let md = fx.read_text("zero/summary.md");
    assert!(
        md.contains("| ours | gps | paper |") && md.contains("n/a"),
        "{md}"
    );
}

/// A sweep over GNSS sigmas is a config: configs/gnss-sweep.toml's levels
/// of its own (docs/pipeline.md shows its command), here on a shorter run
/// with fewer methods. Every level gets its rows; GPS-Hungarian, which
/// reads the reported poses, loses pairs as the sigma grows, while coid,
/// on the paper's inputs, scores the same at every level. A level without
/// sigmas, a name that is no name and sigmas for `none` are refused.
#[test]
fn a_gnss_sigma_sweep_needs_only_a_config() {
    let sweep = std::fs::read_to_string(repo().join("configs/gnss-sweep.toml")).unwrap();
    let fx = Fixture::new();
    let extra = "[eval]\ntraffic_seeds = [1, 2]\n\
                 [matching]\nmethods = [\"gps-hungarian\", \"coid\", \"oracle\"]\n";
    let cfg = fx.config("sweep.toml", 60.0, &format!("{extra}{sweep}"));
    assert_ok(&fx.cmd("eval").quiet().config(&cfg).out("sweep").output());
    let t = read_csv(&fx.path("sweep/table1b.csv"));
    let (m, l, f1) = (strs(&t, "method"), strs(&t, "pose_noise"), f64s(&t, "f1"));
    let at = |method: &str, level: &str| {
        (0..t.height())
            .find(|&i| m[i] == method && l[i] == level)
            .map(|i| f1[i])
            .unwrap_or_else(|| panic!("no row {method} at {level}"))
    };
    let gps = |level: &str| at("gps-hungarian", level);
    assert!(
        gps("gnss-0.5m") > gps("gnss-2m") && gps("gnss-2m") > gps("gnss-4m"),
        "GPS-Hungarian F1 by sigma: {} {} {} {}",
        gps("gnss-0.5m"),
        gps("gnss-1m"),
        gps("gnss-2m"),
        gps("gnss-4m")
    );
    let t1 = read_csv(&fx.path("sweep/table1.csv"));
    let coid: Vec<f64> = (0..t1.height())
        .filter(|&i| strs(&t1, "method")[i] == "coid")
        .map(|i| f64s(&t1, "f1")[i])
        .collect();
    assert_eq!(coid.len(), 5, "coid's rows: {coid:?}");
    assert!(coid.iter().all(|f| *f == coid[0]), "{coid:?}");
    for (body, expect) in [
        (
            "[pose_noise]\nlevels = [\"none\", \"gnss-3m\"]\n",
            "level gnss-3m has no sigmas: add \"gnss-3m\" = {",
        ),
        (
            "[pose_noise]\nlevels = [\"GNSS 3m\"]\n",
            "'GNSS 3m' is no pose-noise level's name",
        ),
        (
            "[pose_noise]\nnone = { position_sigma_m = 1.0, heading_sigma_deg = 0.0 }\n",
            "level none is exact self-localisation",
        ),
    ] {
        let bad = fx.config("bad.toml", 60.0, body);
        assert_refused_unwritten(&fx.run(&bad, "bad"), expect, &fx.path("bad"));
    }
}
