//! `[train]` and `[eval]` scenario lists.

use crate::util::*;

/// `[train] scenarios` and `validation_scenarios` feed `coid train`
/// (their runs are collected, the lambda is validated on the held-out
/// scenario, both are recorded beside the weights), and `[eval]
/// scenarios` joins `coid eval` as its own table and the pooled one.
#[test]
fn train_and_eval_use_the_scenario_lists() {
    let fx = Fixture::new();
    let scenarios = fx
        .cmd("scenarios")
        .quiet()
        .args(["--count", "3", "--seed", "21"]);
    assert_ok(&scenarios.out("fam").output());
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
    let trained = fx.cmd("train").quiet().config(&cfg).out("models").output();
    assert_ok(&trained);
    assert!(
        stderr(&trained).contains("from 2 runs"),
        "{}",
        stderr(&trained)
    );
    let meta = fx.read_text("models/gcn-gm.toml");
    assert!(
        meta.contains("train_scenarios") && meta.contains("s000"),
        "{meta}"
    );
    assert!(
        meta.contains("validation_scenarios") && meta.contains("s001"),
        "{meta}"
    );
    assert_ok(&fx.cmd("eval").quiet().config(&cfg).out("ev").output());
    for dir in ["ev/t", "ev/s002", "ev/pooled"] {
        assert!(fx.path(dir).join("table1.csv").is_file(), "{dir}");
    }
}
