//! Bad input of every kind is refused in one line, before anything is
//! written.

use crate::util::*;
use std::path::{Path, PathBuf};

/// Runs `config` into `out`: refused, and no output folder.
fn fails_cleanly(fx: &Fixture, config: &Path, expect: &str) {
    assert_refused_unwritten(&fx.run(config, "out"), expect, &fx.path("out"));
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
    let (fx, cfg) = Fixture::with_config(60.0, "[sensor]\nrange_sigma = 1.0\n");
    fails_cleanly(&fx, &cfg, "unknown field `range_sigma`");
}

#[test]
fn missing_scenario_file() {
    let fx = Fixture::new();
    let cfg = fx.write("m.toml", &scenario_toml(Path::new("missing.sumocfg"), "C"));
    fails_cleanly(&fx, &cfg, "no such file");
}

#[test]
fn unknown_junction() {
    let fx = Fixture::new();
    let scenario = scenario_toml(&shipped_sumocfg(), "Z9");
    let cfg = fx.write(
        "j.toml",
        &format!("{scenario}end_s = 60\n[matching]\nmethods = [\"oracle\"]\n"),
    );
    fails_cleanly(&fx, &cfg, "junction 'Z9' does not exist");
}

#[test]
fn unknown_connected_vehicle() {
    let (fx, cfg) = Fixture::with_config(60.0, "[connected]\nids = [\"cv0\", \"ghost\"]\n");
    fails_cleanly(&fx, &cfg, "\"ghost\"");
}

/// A config whose SUMO cannot start (its net file does not exist).
fn broken_sumo(fx: &Fixture) -> PathBuf {
    fx.write(
        "broken.sumocfg",
        "<configuration><input><net-file value=\"no-such.net.xml\"/></input></configuration>",
    );
    let scenario = scenario_toml(Path::new("broken.sumocfg"), "C");
    fx.write(
        "s.toml",
        &format!("{scenario}[matching]\nmethods = [\"oracle\"]\n"),
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
    assert_refused(&out, "a-file");
    assert!(!stderr(&out).contains("SUMO"), "{}", stderr(&out));
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
    let scenario = scenario_toml(Path::new("mid.sumocfg"), "C");
    let cfg = fx.write(
        "mid.toml",
        &format!(
            "{scenario}end_s = 60\n[connected]\nids = [\"a\", \"c\"]\n[matching]\nmethods = [\"oracle\"]\n"
        ),
    );
    fails_cleanly(&fx, &cfg, "SUMO failed at t = ");
}

#[test]
fn existing_results_are_kept_without_force() {
    let (fx, cfg) = Fixture::with_config(60.0, "");
    std::fs::create_dir_all(fx.path("out")).unwrap();
    std::fs::write(fx.path("out/summary.csv"), "precious").unwrap();
    assert_refused(&fx.run(&cfg, "out"), "already exists");
    assert_eq!(fx.read_text("out/summary.csv"), "precious");
    // With --force a run folder coid wrote is replaced by a complete
    // new one (a user's folder never is: regression::).
    assert_ok(&fx.run(&cfg, "mine"));
    let before = fx.read("mine/summary.csv");
    let again = fx
        .cmd("run")
        .quiet()
        .arg("--force")
        .config(&cfg)
        .out("mine");
    assert_ok(&again.args(["--traffic-seed", "2"]).output());
    let after = fx.read("mine/summary.csv");
    assert!(after.starts_with(b"method,") && after != before);
}

/// `--force` replaces only what the same command wrote: never a
/// user's folder (here the one holding the run's own config), nor a
/// batch's or another command's results.
#[test]
fn force_replaces_only_results_of_the_same_kind() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("mine")).unwrap();
    let cfg = fx.config("mine/c.toml", 60.0, "");
    let forced = |command: &str| fx.cmd(command).quiet().arg("--force").config(&cfg);
    assert_refused(&forced("run").out("mine").output(), "coid did not write it");
    assert!(cfg.is_file(), "the config was removed");
    assert_ok(&fx.run(&cfg, "r"));
    assert_refused(
        &forced("eval").out("r").output(),
        "replaces only an evaluation",
    );
    let batch = fx.cmd("batch").quiet().config(&cfg).args(["--runs", "1"]);
    assert_refused(&batch.out("r").output(), "not a batch folder");
    let scenarios = fx.cmd("scenarios").quiet().args(["--count", "1"]);
    assert_refused(&scenarios.out("mine").output(), "coid did not write it");
    assert_ok(&forced("run").out("r").output());
}

/// Bounds that would exhaust memory or wrap around, and seeds SUMO
/// cannot take, are refused before anything runs.
#[test]
fn out_of_range_arguments_are_refused() {
    let (fx, c) = Fixture::with_config(60.0, "");
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
    let (fx, cfg) = Fixture::with_config(30.0, "[connected]\npenetration = 0.01\n");
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
    let (fx, cfg) = Fixture::with_config(60.0, "[matching]\nmethods = [\"oracle\"]\n");
    let batch = fx.cmd("batch").quiet().config(&cfg).args(["--runs", "2"]);
    assert_ok(&batch.args(["--shard", "1/2"]).out("s1").output());
    let merged = fx.coid(&["merge", "s1", "./s1", "--out", "m"]);
    assert_refused_unwritten(&merged, "given twice", &fx.path("m"));
}

/// Regression: an unknown decision rule's error listed the rules of an
/// older build (not `mutual-real`); it names every rule the binary has.
#[test]
fn an_unknown_decision_rule_names_every_rule() {
    let (fx, cfg) = Fixture::with_config(5.0, "[matching]\ndecision = \"mutual-reel\"\n");
    fails_cleanly(&fx, &cfg, "assignment, mutual, mutual-real");
}
