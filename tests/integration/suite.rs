//! `coid eval --suite`: tables per scenario and pooled.

use crate::util::*;

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
    assert_refused_unwritten(&refused, "pose-noise levels", &fx.path("ev2"));
}
