//! The configuration's tests: merging, validation, scenario lists, the
//! digest.

use super::digest::sumocfg_inputs;
use super::*;
use crate::matching::LambdaChoice;

fn write_cfg(dir: &Path, body: &str) -> PathBuf {
    std::fs::write(dir.join("scenario.sumocfg"), "<configuration/>").unwrap();
    let path = dir.join("c.toml");
    std::fs::write(&path, body).unwrap();
    path
}

const MINIMAL: &str = "[scenario]\nsumocfg = \"scenario.sumocfg\"\njunction = \"J1\"\n";

/// A folder of scenario folders `s0`, `s1`, ... each with its own SUMO
/// configuration and a `coid.toml`.
fn family(dir: &Path, n: usize) {
    for k in 0..n {
        let d = dir.join("fam").join(format!("s{k}"));
        std::fs::create_dir_all(&d).unwrap();
        write_cfg(&d, MINIMAL);
        std::fs::rename(d.join("c.toml"), d.join("coid.toml")).unwrap();
    }
}

#[test]
fn scenario_lists_expand_folders_and_keep_roles_apart() {
    let dir = tempfile::tempdir().unwrap();
    family(dir.path(), 3);
    let body = format!("{MINIMAL}[train]\nscenarios = [\"fam\"]\nruns_per_scenario = 2\n");
    let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
    let names: Vec<String> = s
        .train
        .scenarios
        .iter()
        .map(|p| {
            p.parent()
                .unwrap()
                .file_name()
                .unwrap()
                .to_string_lossy()
                .into_owned()
        })
        .collect();
    assert_eq!(names, ["s0", "s1", "s2"]);
    assert_eq!(s.train.runs_per_scenario, 2);
    // A scenario folder names itself.
    let body = format!("{MINIMAL}[eval]\nscenarios = [\"fam/s1\"]\n");
    let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
    assert!(s.eval.scenarios[0].ends_with("s1/coid.toml"));
    // One scenario in two roles, named by a folder and by a file.
    let body = format!(
        "{MINIMAL}[train]\nscenarios = [\"fam\"]\n[eval]\nscenarios = [\"fam/s1/coid.toml\"]\n"
    );
    let err = Settings::load(&write_cfg(dir.path(), &body))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("eval.scenarios") && err.contains("disjoint"),
        "{err}"
    );
    let body = format!(
        "{MINIMAL}[train]\nscenarios = [\"fam/s0/coid.toml\"]\nvalidation_scenarios = [\"fam/s0/coid.toml\"]\n"
    );
    let err = Settings::load(&write_cfg(dir.path(), &body))
        .unwrap_err()
        .to_string();
    assert!(err.contains("validation_scenarios"), "{err}");
    // Missing paths, empty folders and impossible run counts.
    for (extra, key) in [
        ("[train]\nscenarios = [\"nowhere\"]\n", "no such file"),
        ("[train]\nscenarios = [\".\"]\n", "holds no scenario folder"),
        ("[train]\nruns_per_scenario = 0\n", "runs_per_scenario"),
        (
            "[train]\nruns_per_scenario = 11\nvalidation_scenarios = [\"../fam/s2\"]\n",
            "runs_per_scenario",
        ),
    ] {
        let empty = dir.path().join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        let err = Settings::load(&write_cfg(&empty, &format!("{MINIMAL}{extra}")))
            .unwrap_err()
            .to_string();
        assert!(err.contains(key), "{extra}: {err}");
    }
}

#[test]
fn the_digest_is_by_content_not_by_path() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("sumo_nets/intersection");
    for d in ["a", "b"] {
        let to = dir.path().join(d);
        std::fs::create_dir_all(&to).unwrap();
        for f in [
            "intersection.sumocfg",
            "intersection.net.xml",
            "intersection.rou.xml",
            "buildings.poly.xml",
        ] {
            std::fs::copy(scenario.join(f), to.join(f)).unwrap();
        }
        let body = "[scenario]\nsumocfg = \"intersection.sumocfg\"\njunction = \"C\"\n";
        std::fs::write(to.join("c.toml"), body).unwrap();
    }
    let load = |d: &str| Settings::load(&dir.path().join(d).join("c.toml")).unwrap();
    let (a, b) = (load("a").digest().unwrap(), load("b").digest().unwrap());
    assert_eq!(a, b, "the same config at two paths");
    // A setting, or a byte of a file the run reads, changes it.
    let routes = dir.path().join("b/intersection.rou.xml");
    let text = std::fs::read_to_string(&routes).unwrap();
    std::fs::write(&routes, format!("{text}\n")).unwrap();
    assert_ne!(load("b").digest().unwrap(), a);
    let mut edited = load("a");
    edited.sensor.colour_sigma += 0.01;
    assert_ne!(edited.digest().unwrap(), a);
    assert_eq!(
        sumocfg_inputs("<net-file value=\"n.xml\"/><route-files value=\"r1.xml, r2.xml\"/>"),
        ["n.xml", "r1.xml", "r2.xml"]
    );
}

#[test]
fn the_defaults_are_the_shipped_file_and_valid() {
    let d = Settings::defaults().unwrap();
    let shipped = Settings::load(&defaults_dir().join("default.toml")).unwrap();
    // Same settings whether the file is read as a user's file or taken
    // as the compiled-in defaults (paths aside: both resolve to the
    // installation).
    assert_eq!(d.scenario.sumocfg, shipped.scenario.sumocfg);
    assert_eq!(d.sensor, shipped.sensor);
    assert_eq!(d.matching.methods.len(), 16);
    assert_eq!(
        d.matching.baselines,
        crate::matching::BaselineChoice::Validated
    );
    assert!(d.matching.sender_as_node);
    assert_eq!(d.matching.lambda, LambdaChoice::Validated);
    assert_eq!(
        d.connected,
        ConnectedSelection::Ids(vec!["cv0".into(), "cv1".into()])
    );
    assert!(d.matching.models_dir.join("ours.bpk").is_file());
    // The shipped [v2x] is the code's default, and at its default it
    // is not part of the text a config's digest hashes (configs from
    // before it keep their digest); changed, it is.
    assert_eq!(d.v2x, V2xSettings::default());
    assert!(!format!("{d:?}").contains("v2x"));
    let mut changed = d.clone();
    changed.v2x.channel.latency_s = 0.3;
    assert!(format!("{changed:?}").contains("v2x"));
    assert_ne!(d.digest().unwrap(), changed.digest().unwrap());
    // The detector and GNSS knobs leave the text of configs without them
    // alone:
    // the low-speed heading error while off, the detector profiles while
    // every vehicle senses with the paper's model.
    assert!(!format!("{changed:?}").contains("gnss_heading_speed_sigma_mps"));
    assert!(!format!("{d:?}").contains("detector"));
    let mut heading = changed.clone();
    heading.v2x.gnss_heading_speed_sigma_mps = 0.05;
    assert!(format!("{heading:?}").contains("gnss_heading_speed_sigma_mps"));
    let mut drift = d.clone();
    drift.v2x.gnss_correlation_s = 30.0;
    assert!(format!("{drift:?}").contains("ideal_gnss_drift"));
    let mut lidar = d.clone();
    lidar.detector.profile = crate::sensor::profile::DetectorProfile::Lidar;
    assert_ne!(d.digest().unwrap(), lidar.digest().unwrap());
    // Digest format 2: how unset colours look is always in the text (it
    // changes results on demand without colours, and batches made before
    // it existed kept SUMO's yellow), so every digest changed once.
    assert!(format!("{d:?}").contains("unset_colours: Drawn"));
    let mut yellow = d.clone();
    yellow.sensor.unset_colours = crate::traffic::UnsetColours::Sumo;
    assert_ne!(d.digest().unwrap(), yellow.digest().unwrap());
}

#[test]
fn a_minimal_user_file_gets_the_defaults_and_its_own_paths() {
    let dir = tempfile::tempdir().unwrap();
    let s = Settings::load(&write_cfg(dir.path(), MINIMAL)).unwrap();
    let d = Settings::defaults().unwrap();
    assert!(
        s.scenario
            .sumocfg
            .starts_with(dir.path().canonicalize().unwrap())
    );
    assert_eq!(s.scenario.junction, "J1");
    assert_eq!(s.scenario.end_s, d.scenario.end_s);
    assert_eq!(
        (&s.sensor, &s.camera, &s.pose_noise),
        (&d.sensor, &d.camera, &d.pose_noise)
    );
    // The shipped models, not a folder beside the user's file.
    assert_eq!(s.matching.models_dir, d.matching.models_dir);
    assert_eq!(s.pose_noise[2].position_sigma_m, 1.2);
}

#[test]
fn tables_merge_key_by_key_but_connected_is_replaced_whole() {
    let dir = tempfile::tempdir().unwrap();
    let body = format!(
        "{MINIMAL}[connected]\npenetration = 0.3\n[pose_noise]\nrtk = {{ position_sigma_m = 0.5 }}\n[camera]\nrange_m = 50.0\n"
    );
    let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
    assert_eq!(s.connected, ConnectedSelection::Penetration(0.3));
    assert_eq!(s.pose_noise[1].position_sigma_m, 0.5);
    assert!((s.pose_noise[1].heading_sigma_rad - 0.2f64.to_radians()).abs() < 1e-15);
    assert_eq!(
        (s.camera.range_m, s.camera.yaw_offsets_rad.len()),
        (50.0, 1)
    );
}

#[test]
fn a_user_scenario_needs_its_own_junction() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_cfg(dir.path(), "[scenario]\nsumocfg = \"scenario.sumocfg\"\n");
    let e = Settings::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("scenario.junction") && e.contains("missing"),
        "{e}"
    );
}

#[test]
fn unknown_key_is_an_error_with_the_users_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_cfg(dir.path(), &format!("{MINIMAL}\n[camera]\nfov = 90\n"));
    let e = Settings::load(&path).unwrap_err().to_string();
    assert!(e.contains("unknown field `fov`"), "{e}");
    assert!(e.contains(":6:"), "{e}");
    assert!(!e.contains('\n'));
    let path = write_cfg(
        dir.path(),
        &format!("{MINIMAL}[seeds]\ntraffic = \"one\"\n"),
    );
    let e = Settings::load(&path).unwrap_err().to_string();
    assert!(e.contains(":5:"), "{e}");
}

#[test]
fn bad_values_are_named() {
    let dir = tempfile::tempdir().unwrap();
    for (extra, key) in [
        ("[camera]\nfov_deg = 200.0\n", "camera.fov_deg"),
        ("[connected]\npenetration = 1.5\n", "connected.penetration"),
        ("[seeds]\ntraffic = 2147483648\n", "seeds.traffic"),
        ("[matching]\nmethods = [\"external\"]\n", "matching.methods"),
        ("[v2x]\nstep_length_s = 0.0\n", "v2x.step_length_s"),
        ("[v2x.cpm]\nrate_hz = 20.0\n", "v2x.cpm.rate_hz"),
        ("[v2x.cpm]\nmax_objects = 0\n", "v2x.cpm.max_objects"),
        (
            "[v2x.channel]\nloss_probability = 1.5\n",
            "v2x.channel.loss_probability",
        ),
        (
            "[v2x.tracker]\nconfirm_hits = 0\n",
            "v2x.tracker.confirm_hits",
        ),
        ("[v2x]\nmatcher = \"oracle\"\n", "v2x.matcher"),
        (
            "[v2x.tracker]\nappearance_sigma = -0.1\n",
            "v2x.tracker.appearance_sigma",
        ),
        ("[v2x.tracker]\nreid_s = -1.0\n", "v2x.tracker.reid_s"),
        (
            "[v2x.association]\nsmoothing = 0.0\n",
            "v2x.association.smoothing",
        ),
        (
            "[v2x.association]\nthreshold = 1.0\n",
            "v2x.association.threshold",
        ),
        ("[eval]\ntraffic_seeds = [1, 2, 1]\n", "eval.traffic_seeds"),
        (
            "[eval]\ntraffic_seeds = [3000000000]\n",
            "eval.traffic_seeds",
        ),
        (
            "[train]\nvalidation_seeds = [125, 125]\n",
            "train.validation_seeds",
        ),
        (
            "[sensor]\nfalse_positives_per_frame = 1e9\n",
            "sensor.false_positives_per_frame",
        ),
        ("[connected]\nids = [\"a\"]\n", "connected.ids"),
        (
            "[connected]\npenetration = 0.3\ncomm_range_m = -5.0\n",
            "connected.comm_range_m",
        ),
        (
            "[connected]\npenetration = 0.3\nmax_peers = 0\n",
            "connected.max_peers",
        ),
        (
            "[connected]\nids = [\"a\", \"b\"]\npenetration = 0.3\n",
            "connected",
        ),
        ("[sensor]\nmiss_prob_base = -0.1\n", "sensor.miss_prob_base"),
        ("[train]\ntraffic_seeds = [1]\n", "train.traffic_seeds"),
        (
            "[train]\nvalidation_seeds = [101]\n",
            "train.validation_seeds",
        ),
        (
            "[train]\nvalidation_seeds = [3]\n",
            "train.validation_seeds",
        ),
        ("[matching]\nlambda = \"best\"\n", "matching.lambda"),
        ("[matching]\nlambda = 1.5\n", "matching.lambda"),
        ("[matching]\nrematch = 11\n", "matching.rematch"),
        ("[matching]\ndecision = \"best\"\n", "matching.decision"),
        (
            "[fusion]\nalign_min_matches = 1\n",
            "fusion.align_min_matches",
        ),
    ] {
        let path = write_cfg(dir.path(), &format!("{MINIMAL}{extra}"));
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(e.contains(key), "{extra}: {e}");
    }
}

#[test]
fn missing_sumocfg_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.toml");
    std::fs::write(
        &path,
        "[scenario]\nsumocfg = \"nope.sumocfg\"\njunction = \"C\"\n",
    )
    .unwrap();
    let e = Settings::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("no such file") && e.contains("nope.sumocfg"),
        "{e}"
    );
}

#[test]
fn unknown_method_lists_the_known_ones() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_cfg(
        dir.path(),
        &format!("{MINIMAL}[matching]\nmethods = [\"magic\"]\n"),
    );
    let e = Settings::load(&path).unwrap_err().to_string();
    assert!(e.contains("magic") && e.contains("oracle"), "{e}");
    assert!(e.contains(":5:"), "{e}");
}

/// Every key the validation names by hand (in errors, lists, seeds) is a
/// key of the defaults file: a misspelt key would send the user to a key
/// that does not exist. (Numeric checks take their key from the field
/// itself, `check::field!`.)
#[test]
fn every_key_named_in_messages_exists_in_the_defaults() {
    let defaults: toml::Table = DEFAULTS_TOML.parse().unwrap();
    let mut keys = std::collections::BTreeSet::new();
    fn walk(t: &toml::Table, prefix: &str, keys: &mut std::collections::BTreeSet<String>) {
        for (k, v) in t {
            let name = format!("{prefix}{k}");
            if let toml::Value::Table(inner) = v {
                walk(inner, &format!("{name}."), keys);
            }
            keys.insert(name);
        }
    }
    walk(&defaults, "", &mut keys);
    // Optional keys the defaults leave commented out.
    for k in [
        "connected.ids",
        "connected.penetration",
        "connected.comm_range_m",
        "connected.max_peers",
    ] {
        keys.insert(k.into());
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/config");
    let mut named = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.ends_with("tests.rs") {
            continue;
        }
        let text = std::fs::read_to_string(&p).unwrap();
        for (k, _) in text.match_indices('"') {
            let rest = &text[k + 1..];
            let Some(end) = rest.find('"') else { continue };
            let word = &rest[..end];
            let looks_like_key = word.contains('.')
                && word
                    .chars()
                    .all(|c| c.is_ascii_lowercase() || c == '_' || c == '.' || c.is_ascii_digit())
                && !word.starts_with('.')
                && !word.ends_with('.')
                && !word.ends_with("toml");
            let section = word.split('.').next().unwrap_or("");
            if looks_like_key && defaults.contains_key(section) {
                named += 1;
                assert!(
                    keys.contains(word),
                    "{}: \"{word}\" is not a key",
                    p.display()
                );
            }
        }
    }
    assert!(named > 20, "only {named} keys found: the scan is broken");
}

#[test]
fn every_shipped_config_loads() {
    let mut n = 0;
    for entry in std::fs::read_dir(defaults_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            Settings::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            n += 1;
        }
    }
    assert!(n >= 4, "{n} configs");
}

/// A level of a config's own carries its sigmas and, when it gives one,
/// its correlation time (then in the digest; a level without one leaves
/// the digest as it was); bad values are refused by the level's name.
#[test]
fn a_defined_level_carries_its_sigmas_and_correlation_time() {
    let dir = tempfile::tempdir().unwrap();
    let body = "[pose_noise]\nlevels = [\"none\", \"drift-2m\", \"gps\"]\n\
                \"drift-2m\" = { position_sigma_m = 2.0, heading_sigma_deg = 0.5, correlation_s = 30.0 }\n";
    let s = Settings::load(&write_cfg(dir.path(), body)).unwrap();
    let names: Vec<&str> = s.pose_noise.iter().map(|l| l.label.as_str()).collect();
    // Reported as levels are ordered: the built-in ones first.
    assert_eq!(names, ["none", "gps", "drift-2m"]);
    let drift = s.pose_noise[2];
    assert_eq!(
        (drift.position_sigma_m, drift.correlation_s),
        (2.0, Some(30.0))
    );
    assert!((drift.heading_sigma_rad - 0.5_f64.to_radians()).abs() < 1e-15);
    assert_eq!(drift.correlation_s(0.0), 30.0);
    assert_eq!(s.pose_noise[1].correlation_s, None);
    assert_eq!(s.pose_noise[1].correlation_s(7.0), 7.0);
    assert!(format!("{s:?}").contains("correlation_s: 30.0"));
    assert!(format!("{s:?}").contains("ideal_gnss_drift"));
    let d = Settings::defaults().unwrap();
    assert!(!format!("{d:?}").contains("correlation_s:"));
    let bad = "[pose_noise]\nlevels = [\"x\"]\nx = { position_sigma_m = 1.0, heading_sigma_deg = 0.0, correlation_s = -1.0 }\n";
    let e = Settings::load(&write_cfg(dir.path(), bad))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("level x: correlation_s must be in [0, 1000000] s, got -1"),
        "{e}"
    );
}

/// A point of the MC sweep is checked as a config's `[matching]
/// mc_samples` and `mc_dropout` are, and leaves the settings it came from
/// as they were.
#[test]
fn a_sweep_point_is_checked_like_a_config_and_leaves_the_settings_alone() {
    let base = Settings::defaults().unwrap();
    let s = base.with_inference(40, Some(0.3)).unwrap();
    assert_eq!(
        (s.matching.mc_samples, s.matching.mc_dropout),
        (40, Some(0.3))
    );
    assert_eq!(base, Settings::defaults().unwrap());
    let e = base.with_inference(100_000, None).unwrap_err();
    assert!(
        e.to_string().contains("matching.mc_samples: must be 1 to"),
        "{e}"
    );
    let e = base.with_inference(20, Some(0.99)).unwrap_err();
    assert!(
        e.to_string()
            .contains("matching.mc_dropout: must be a rate"),
        "{e}"
    );
}
