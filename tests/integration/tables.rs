//! What each method sees, and thresholds chosen for every method alike:
//! a renamed method is refused with its new name, weights of the project's
//! network recorded under a name the published networks took are refused
//! with the new name, and the baselines' thresholds come from the
//! validation runs (or are fixed a priori, as the config says).

use crate::util::*;

/// A config naming `ours-noprior` (the paper's network with the reported
/// heading, replaced by `coid` on the paper's inputs) is refused in one
/// line that names `coid`, before anything runs.
#[test]
fn r33_a_renamed_method_in_an_old_config_is_refused_with_its_new_name() {
    let (fx, cfg) = Fixture::with_config(
        60.0,
        "[matching]\nmethods = [\"ours-noprior\", \"oracle\"]\n",
    );
    let out = fx.run(&cfg, "out");
    assert_refused_unwritten(&out, "was renamed: write 'coid'", &fx.path("out"));
    assert_eq!(stderr(&out).trim().lines().count(), 1, "{}", stderr(&out));
}

/// A models folder of before the renaming (the project's network with
/// DGMC's terms recorded as `dgmc`) is refused for `dgmc`, DGMC as
/// published, with the name those weights have now.
#[test]
fn r33_old_weights_under_a_published_name_are_refused_with_their_new_name() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("models")).unwrap();
    let shipped = repo().join("models");
    // The project's network, as `ours` ships it, recorded as `dgmc`.
    std::fs::copy(shipped.join("ours.bpk"), fx.path("models/dgmc.bpk")).unwrap();
    let record = std::fs::read_to_string(shipped.join("ours.toml"))
        .unwrap()
        .replace("method = \"ours\"", "method = \"dgmc\"");
    std::fs::write(fx.path("models/dgmc.toml"), record).unwrap();
    let cfg = fx.method_config("old.toml", "dgmc", "models");
    let out = fx.run(&cfg, "out");
    assert_refused_unwritten(&out, "now called 'dgmc+gps'", &fx.path("out"));
}

/// The deep baselines with the poses (`dgmc+gps`, ...) are not shipped
/// (only weights of the shipped recipe, three seeds each, are): a run
/// naming one with the shipped models folder is refused before anything
/// runs, with the command that trains it.
#[test]
fn r33_an_unshipped_deep_baseline_names_the_command_that_trains_it() {
    let (fx, cfg) =
        Fixture::with_config(60.0, "[matching]\nmethods = [\"dgmc+gps\", \"oracle\"]\n");
    let out = fx.run(&cfg, "out");
    assert_refused_unwritten(&out, "run `coid train --methods dgmc+gps`", &fx.path("out"));
}

/// `coid train --validate-only` works on the models folder it validates:
/// the folder must exist, so it needs no `--force` (it did, and every user
/// validating weights met "already exists").
#[test]
fn r33_validate_only_needs_no_force() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("models")).unwrap();
    let cfg = fx.config(
        "v.toml",
        60.0,
        "[train]\nvalidation_seeds = [125]\n[pose_noise]\nlevels = [\"gps\"]\n\
         [matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n",
    );
    let cmd = fx.cmd("train").quiet().config(&cfg).out("models");
    let tuned = cmd
        .args(["--validate-only", "--methods", "gps-hungarian"])
        .output();
    assert_ok(&tuned);
    assert!(fx.read_text("models/baselines.toml").contains("gate_chi2"));
}

/// `coid train --validate-only --methods gps-hungarian` chooses the gate
/// on the validation run from its grid and records it with its F1 and the
/// a-priori value's; a run then uses it (`baselines = "validated"`), a
/// models folder without the record is refused with the remedy, and
/// `baselines = "a-priori"` runs without one.
#[test]
fn baseline_thresholds_are_chosen_on_the_validation_runs() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("models")).unwrap();
    let matching = |baselines: &str| {
        format!(
            "[train]\nvalidation_seeds = [125]\n[pose_noise]\nlevels = [\"gps\"]\n\
             [matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\nbaselines = \"{baselines}\"\n\
             models_dir = {:?}\n",
            fx.path("models").to_string_lossy()
        )
    };
    let cfg = fx.config("v.toml", 60.0, &matching("validated"));
    let refused = fx.run(&cfg, "before");
    assert_refused_unwritten(&refused, "coid train --validate-only", &fx.path("before"));
    let tune = || {
        let cmd = fx.cmd("train").quiet().config(&cfg).out("models");
        cmd.args(["--validate-only", "--force", "--methods", "gps-hungarian"])
            .output()
    };
    let tuned = tune();
    assert_ok(&tuned);
    // A models folder holding the record is still one coid may extend.
    assert_ok(&tune());
    let record = fx.read_text("models/baselines.toml");
    let value: f64 = record
        .lines()
        .find_map(|l| l.strip_prefix("value = "))
        .unwrap()
        .parse()
        .unwrap();
    let grid = [4.61, 5.99, 9.21, 13.82, 18.42, 23.03, 27.63];
    assert!(grid.contains(&value), "{record}");
    for key in [
        "parameter = \"gate_chi2\"",
        "a_priori = 9.21",
        "f1_a_priori = ",
        "validation_seeds = [125]",
    ] {
        assert!(record.contains(key), "{key}: {record}");
    }
    assert!(
        stderr(&tuned).contains("gps-hungarian: gate_chi2"),
        "{}",
        stderr(&tuned)
    );
    assert_ok(&fx.run(&cfg, "validated"));
    let a_priori = fx.config("a.toml", 60.0, &matching("a-priori"));
    std::fs::remove_file(fx.path("models/baselines.toml")).unwrap();
    assert_ok(&fx.run(&a_priori, "a-priori"));
}
