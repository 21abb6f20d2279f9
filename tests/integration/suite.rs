//! `coid eval --suite`: tables per scenario and pooled.

use crate::util::*;
use std::path::Path;

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
    let scenarios = fx
        .cmd("scenarios")
        .quiet()
        .args(["--count", "1", "--seed", "3"]);
    assert_ok(&scenarios.out("fam").output());
    let own = fx.read_text("fam/s000/coid.toml");
    let generated = fx.write(
        "fam/s000/short.toml",
        &(own
            .replace("end_s = 150.0", "end_s = 60.0")
            .replace("penetration = 0.1", "penetration = 0.3")
            + &format!("{levels}[eval]\ntraffic_seeds = [3]\n")),
    );
    let suite = |other: &Path, out: &str| {
        let cmd = fx.cmd("eval").quiet().config(&base);
        cmd.arg("--suite").arg(other).out(out).output()
    };
    assert_ok(&suite(&generated, "ev"));
    let runs = |dir: &str| f64s(&read_csv(&fx.path(dir).join("table1b.csv")), "n_runs")[0];
    assert_eq!(runs("ev/base"), 2.0);
    assert_eq!(runs("ev/short"), 1.0);
    assert_eq!(runs("ev/pooled"), 3.0);
    // eval runs the configured methods only.
    let mut methods = strs(&read_csv(&fx.path("ev/pooled/table1b.csv")), "method");
    methods.dedup();
    assert_eq!(methods, ["gps-hungarian", "oracle"]);
    let md = fx.read_text("ev/pooled/summary.md");
    assert!(md.contains("base, short"), "{md}");
    // Other pose-noise levels cannot be pooled.
    let other = fx.config("other.toml", 60.0, "[pose_noise]\nlevels = [\"gps\"]\n");
    let refused = suite(&other, "ev2");
    assert_refused_unwritten(&refused, "pose-noise levels", &fx.path("ev2"));
}
