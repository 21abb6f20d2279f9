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
