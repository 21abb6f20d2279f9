//! The learned methods: training, early stopping, training in child
//! processes, weights checked against their record, the shipped model
//! against the strongest baseline.

use crate::util::*;

/// Real burn training on a small real data set (one SUMO run, one
/// epoch), then a run that loads the weights it wrote.
#[test]
fn train_writes_loadable_weights_and_a_loss_curve() {
    let fx = Fixture::new();
    let cfg = fx.config(
        "t.toml",
        80.0,
        &format!(
            "[train]\ntraffic_seeds = [201]\nepochs = 1\nmethods = [\"gcn-gm\"]\n[matching]\nmethods = [\"gcn-gm\", \"oracle\"]\nmodels_dir = {:?}\n[pose_noise]\nlevels = [\"gps\"]\n",
            fx.path("results/t-models").to_string_lossy()
        ),
    );
    // Without --out: a new folder, results/<config stem>-models, never
    // the shipped weights; a second time only with --force.
    let train = || fx.cmd("train").quiet().config(&cfg).output();
    assert_ok(&train());
    for f in ["gcn-gm.bpk", "gcn-gm.toml", "gcn-gm_loss.csv"] {
        assert!(fx.path("results/t-models").join(f).is_file(), "{f} missing");
    }
    assert_refused(&train(), "already exists");
    let curve = fx.read_text("results/t-models/gcn-gm_loss.csv");
    // Epoch 0 holds the validation loss before training only.
    let loss: f64 = curve
        .lines()
        .find(|l| l.starts_with("1,"))
        .unwrap()
        .split(',')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!(loss.is_finite() && loss > 0.0, "{curve}");
    assert_ok(&fx.run(&cfg, "with-model"));
    let summary = read_csv(&fx.path("with-model/summary.csv"));
    assert!(strs(&summary, "method").iter().any(|m| m == "gcn-gm"));
}

/// Training lowers the loss on held-out validation runs of real SUMO
/// data (one training run, one validation run; early stopping keeps
/// the epoch with the lowest validation loss and records it).
#[test]
fn training_lowers_the_validation_loss_on_real_runs() {
    let fx = Fixture::new();
    let cfg = fx.config(
        "t.toml",
        80.0,
        &format!(
            "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 3\npatience = 2\n\
             methods = [\"gcn-gm\"]\n[matching]\nmodels_dir = {:?}\n[pose_noise]\nlevels = [\"gps\"]\n",
            fx.path("models").to_string_lossy()
        ),
    );
    assert_ok(&fx.cmd("train").quiet().config(&cfg).out("models").output());
    let curve = read_csv(&fx.path("models/gcn-gm_loss.csv"));
    let v = f64s(&curve, "validation_loss");
    assert!(v.len() >= 2 && v.iter().all(|l| l.is_finite()), "{v:?}");
    let best = v[1..].iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        best < v[0],
        "validation loss before training {} never beaten: {v:?}",
        v[0]
    );
    let meta = fx.read_text("models/gcn-gm.toml");
    assert!(meta.contains("best_epoch = "), "{meta}");
}

/// Two methods trained in two child processes give the same weights,
/// losses and lambdas as one after the other in one process.
#[test]
fn training_in_child_processes_gives_the_same_models() {
    let (fx, cfg) = Fixture::with_config(
        60.0,
        "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 1\n\
         methods = [\"gcn-gm\", \"dgmc\"]\n[pose_noise]\nlevels = [\"gps\"]\n",
    );
    let train = |out: &str, workers: &str| {
        let cmd = fx.cmd("train").quiet().config(&cfg).out(out);
        cmd.args(["-w", workers]).output()
    };
    let two = train("two", "2");
    assert_ok(&two);
    assert_ok(&train("one", "1"));
    for m in ["gcn-gm", "dgmc"] {
        let read = |dir: &str, ext: &str| fx.read(&format!("{dir}/{m}{ext}"));
        assert_eq!(
            read("two", ".bpk"),
            read("one", ".bpk"),
            "{m} weights differ"
        );
        assert_eq!(
            read("two", "_loss.csv"),
            read("one", "_loss.csv"),
            "{m} losses differ"
        );
        let lambda = |dir: &str| {
            String::from_utf8(read(dir, ".toml"))
                .unwrap()
                .lines()
                .skip_while(|l| *l != "[validation]")
                .find(|l| l.starts_with("lambda = "))
                .map(str::to_owned)
        };
        assert!(lambda("two").is_some());
        assert_eq!(lambda("two"), lambda("one"));
    }
    assert!(stderr(&two).contains("trained dgmc"), "{}", stderr(&two));
}

/// Weights that are not the ones their record names (here another
/// method's) are refused with one line, before anything runs.
#[test]
fn weights_that_do_not_match_their_record_are_refused() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("models")).unwrap();
    for f in ["ours.bpk", "ours.toml"] {
        std::fs::copy(repo().join("models").join(f), fx.path("models").join(f)).unwrap();
    }
    std::fs::copy(repo().join("models/gcn-gm.bpk"), fx.path("models/ours.bpk")).unwrap();
    let cfg = fx.method_config("w.toml", "ours", "models");
    let out = fx.run(&cfg, "w");
    assert_refused_unwritten(&out, "not the ones recorded", &fx.path("w"));
    assert!(stderr(&out).contains("ours"), "{}", stderr(&out));
}

#[test]
fn missing_weights_are_a_clear_error() {
    let fx = Fixture::new();
    let cfg = fx.method_config("m.toml", "ours", "nowhere");
    let out = fx.run(&cfg, "out");
    assert_refused(&out, "coid train");
    assert!(stderr(&out).contains("ours"), "{}", stderr(&out));
}

/// Average precision in `precision_recall.csv`: at most the recall the
/// curve ends at (pairs a method never decides are never retrieved); the
/// oracle's is 1.
fn ap_is_at_most_the_recall_it_reaches(path: &std::path::Path) {
    // Average precision: at most the recall the curve ends at (pairs a
    // method never decides are never retrieved); the oracle's is 1.
    let pr = read_csv(path);
    let (ap, end) = (
        f64s(&pr, "ap_pooled"),
        f64s(&pr, "recall_at_operating_point"),
    );
    for (k, name) in strs(&pr, "method").iter().enumerate() {
        assert!(
            ap[k] >= 0.0 && ap[k] <= end[k] + 1e-12,
            "{name}: AP {} recall {}",
            ap[k],
            end[k]
        );
        if name == "oracle" {
            assert!((ap[k] - 1.0).abs() < 1e-12, "{name}: {}", ap[k]);
        }
    }
}

/// The shipped default weights on a small fixed test set (two test runs,
/// never used in training or validation) at 1.2 m pose noise: the full
/// method must beat the strongest baseline, GPS+appearance Hungarian,
/// in F1.
#[test]
fn shipped_model_beats_gps_appearance_hungarian_at_gps_noise() {
    let (fx, cfg) = Fixture::with_config(
        130.0,
        "[pose_noise]\nlevels = [\"gps\"]\n[eval]\ntraffic_seeds = [1, 2]\n",
    );
    assert_ok(&fx.cmd("eval").quiet().config(&cfg).out("ev").output());
    let t1 = read_csv(&fx.path("ev/table1b.csv"));
    let (m, f1) = (strs(&t1, "method"), f64s(&t1, "f1"));
    let f1_of = |name: &str| f1[m.iter().position(|x| x == name).unwrap()];
    assert!(
        f1_of("ours") > f1_of("gps-app-hungarian"),
        "ours F1 {} vs gps-app-hungarian F1 {}",
        f1_of("ours"),
        f1_of("gps-app-hungarian")
    );
    for f in [
        "table2.csv",
        "table3.csv",
        "lambda_sweep.csv",
        "case_study.csv",
        "summary.md",
        "calibration.csv",
        "lambda_sweep.svg",
        "error_cdf.svg",
        "f1_per_method.svg",
        "pr_curve.svg",
        "reliability_ours.svg",
        "precision_recall.csv",
        "pr_curve.csv",
    ] {
        assert!(fx.path("ev").join(f).is_file(), "{f} missing");
    }
    // The claim hedged by the match is never tighter than Eq. 16's (the
    // mixture holds Eq. 16's covariance and wider ones), so its NEES is
    // never larger; both are measured for every row.
    let errors = read_csv(&fx.path("ev/errors.csv"));
    let (eq16, hedged) = (
        f64s(&errors, "nees_fused"),
        f64s(&errors, "nees_fused_hedged"),
    );
    for (k, name) in strs(&errors, "method").iter().enumerate() {
        assert!(
            hedged[k] > 0.0 && hedged[k] <= eq16[k] * (1.0 + 1e-9),
            "{name}: {hedged:?} {eq16:?}"
        );
    }
    let cal = read_csv(&fx.path("ev/calibration.csv"));
    for c in ["method", "pose_noise", "ece", "brier", "auroc"] {
        assert!(cal.column(c).is_ok(), "calibration.csv lacks {c}");
    }
    // Every method identified pairs here, so each row is measured on
    // them: a count above zero and the three measures in [0, 1].
    let (n, ece) = (f64s(&cal, "n_pairs"), f64s(&cal, "ece"));
    let (brier, auroc) = (f64s(&cal, "brier"), f64s(&cal, "auroc"));
    for (k, name) in strs(&cal, "method").iter().enumerate() {
        assert!(n[k] > 0.0, "{name}: no identified pairs");
        for v in [ece[k], brier[k]] {
            assert!((0.0..=1.0).contains(&v), "{name}: {v}");
        }
        // The oracle is never wrong, so the AUROC is undefined for it.
        assert_eq!(auroc[k].is_nan(), name == "oracle", "{name}: {}", auroc[k]);
    }
    ap_is_at_most_the_recall_it_reaches(&fx.path("ev/precision_recall.csv"));
    for (plot, w, h) in [
        ("lambda_sweep", 420, 380),
        ("error_cdf", 420, 380),
        ("reliability_ours", 420, 380),
        ("pr_curve", 420, 380),
        ("f1_per_method", 90, 420), // 90 px per method
    ] {
        let img = image::open(fx.path("ev").join(format!("{plot}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(img.height(), h, "{plot}");
        assert_eq!(img.width() % w, 0, "{plot}: width {}", img.width());
        let ink = img.pixels().filter(|p| p.0 != [255, 255, 255]).count() as f64;
        let share = ink / f64::from(img.width() * img.height());
        assert!(share > 0.03 && share < 0.9, "{plot}: ink share {share}");
    }
}

/// `coid eval --mc-sweep` (Fig. 8b): every sample count and dropout rate
/// on the validation and the test runs, one row per method (the paper's
/// method and ours), setting, split and level; T = 1 (one dropout draw)
/// is a row of its own; the picture is
/// drawn; the sweep cannot be asked of another run list.
#[test]
fn the_mc_sweep_covers_samples_and_dropout_on_both_splits() {
    let (fx, cfg) = Fixture::with_config(
        60.0,
        "[train]\nvalidation_seeds = [125]\n[eval]\ntraffic_seeds = [1]\n[pose_noise]\nlevels = [\"gps\"]\n",
    );
    assert_ok(
        &fx.cmd("eval")
            .quiet()
            .config(&cfg)
            .out("sw")
            .arg("--mc-sweep")
            .output(),
    );
    let t = read_csv(&fx.path("sw/mc_sweep.csv"));
    // 19 settings, 2 splits, 2 methods (coid and ours; one level each).
    assert_eq!(t.height(), 19 * 2 * 2, "{t}");
    let (factor, split) = (strs(&t, "factor"), strs(&t, "split"));
    let method = strs(&t, "method");
    let value = f64s(&t, "value");
    assert_eq!(
        (
            method[0].as_str(),
            factor[0].as_str(),
            value[0],
            split[0].as_str()
        ),
        ("coid", "samples", 1.0, "validation")
    );
    assert_eq!(method[1], "ours");
    assert_eq!((factor[2].as_str(), split[2].as_str()), ("samples", "test"));
    assert!(factor[44..].iter().all(|f| f == "dropout"));
    let f1 = f64s(&t, "f1");
    assert!(f1.iter().all(|f| (0.0..=1.0).contains(f)), "{t}");
    assert!(fx.path("sw/mc_sweep.png").is_file());
    let o = fx
        .cmd("eval")
        .quiet()
        .config(&cfg)
        .out("x")
        .args(["--mc-sweep", "--validation"])
        .output();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

/// A deep method trained with two seeds in one command (`coid train
/// --seed 7,8 --out models`: seed 8 into models/seed-8) and evaluated
/// with `[eval] training_seeds`: Table 1b gives its row as the mean over
/// the seeds, with each seed's F1 (as evaluating that seed's weights
/// alone gives it) as the spread; the paired table counts the seeds; a
/// listed seed without weights is named in a warning with the command
/// that makes them, and one with another seed's weights is refused.
#[test]
fn training_seeds_give_each_deep_row_its_spread_over_seeds() {
    let fx = Fixture::new();
    let body = |models: &str, seeds: &str| {
        format!(
            "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 2\nlearning_rate = 0.05\nseed = 7\n\
             methods = [\"ours\"]\n[eval]\ntraffic_seeds = [1, 2]\ntraining_seeds = {seeds}\n\
             [matching]\nmethods = [\"ours\", \"gps-hungarian\", \"oracle\"]\nbaselines = \"a-priori\"\n\
             models_dir = {:?}\n[pose_noise]\nlevels = [\"gps\"]\n",
            fx.path(models).to_string_lossy()
        )
    };
    let cfg = fx.config("s.toml", 60.0, &body("models", "[7, 8]"));
    // Both seeds in one command, one child each: [train] seed's weights
    // in the models folder, seed 8's in its seed-8 folder, the same bytes
    // as seed 8 trained alone.
    let train = fx
        .cmd("train")
        .quiet()
        .config(&cfg)
        .args(["--seed", "7,8", "-w", "2"]);
    assert_ok(&train.out("models").output());
    assert!(fx.read_text("models/ours.toml").contains("seed = 7"));
    assert!(fx.read_text("models/seed-8/ours.toml").contains("seed = 8"));
    let alone = fx.cmd("train").quiet().config(&cfg).args(["--seed", "8"]);
    assert_ok(&alone.out("alone").output());
    assert_eq!(
        fx.read("alone/seed-8/ours.bpk"),
        fx.read("models/seed-8/ours.bpk")
    );
    assert!(!fx.path("alone/ours.bpk").exists());
    let eval = |cfg: &std::path::Path, out: &str| {
        let o = fx.cmd("eval").quiet().config(cfg).out(out).output();
        assert_ok(&o);
        read_csv(&fx.path(&format!("{out}/table1b.csv")))
    };
    let both = eval(&cfg, "both");
    let row = strs(&both, "method")
        .iter()
        .position(|m| m == "ours")
        .unwrap();
    assert_eq!(strs(&both, "training_seeds")[row], "7 8");
    let alone = |models: &str, out: &str| {
        let c = fx.config(&format!("{out}.toml"), 60.0, &body(models, "[]"));
        let t = eval(&c, out);
        assert!(t.column("training_seeds").is_err(), "one seed, no spread");
        let k = strs(&t, "method").iter().position(|m| m == "ours");
        f64s(&t, "f1")[k.unwrap()]
    };
    let (f7, f8) = (alone("models", "seven"), alone("models/seed-8", "eight"));
    // The two seeds' weights decide differently on these runs, so the
    // spread says which seed is which.
    assert_ne!(f7, f8);
    let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(near(f64s(&both, "f1_seeds_min")[row], f7.min(f8)));
    assert!(near(f64s(&both, "f1_seeds_max")[row], f7.max(f8)));
    let baseline = strs(&both, "method")
        .iter()
        .position(|m| m == "gps-hungarian");
    assert_eq!(strs(&both, "training_seeds")[baseline.unwrap()], "");
    let paired = read_csv(&fx.path("both/paired.csv"));
    let k = strs(&paired, "method").iter().position(|m| m == "ours");
    assert_eq!(f64s(&paired, "n_training_seeds")[k.unwrap()], 2.0);
    // A listed seed without weights: a warning with the command that
    // makes them, and the row averages the seeds it has.
    let missing = fx.config("m.toml", 60.0, &body("models", "[7, 8, 9]"));
    let o = fx.cmd("eval").quiet().config(&missing).out("m").output();
    assert_ok(&o);
    // r33: the command repeats the recipe of the weights beside it (their
    // record's config), not the defaults' training runs.
    let hint = format!("coid train -c {} --seed 9 --methods ours", cfg.display());
    assert!(stderr(&o).contains(&hint), "{}", stderr(&o));
    let t = read_csv(&fx.path("m/table1b.csv"));
    assert_eq!(strs(&t, "training_seeds")[row], "7 8");
    // A listed seed whose folder holds another seed's weights is refused.
    let dir = fx.path("models/seed-9");
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["ours.bpk", "ours.toml"] {
        std::fs::copy(fx.path("models/seed-8").join(f), dir.join(f)).unwrap();
    }
    let o = fx.cmd("eval").quiet().config(&missing).out("m2").output();
    assert_refused(&o, "trained with seed 8, not 9");
    // So is one trained with another recipe: a mean over recipes is not
    // a spread over seeds.
    let record = fx.read_text("models/seed-9/ours.toml");
    let edited = record
        .replace("seed = 8", "seed = 9")
        .replace("epochs = 2", "epochs = 3");
    assert_ne!(edited, record);
    std::fs::write(dir.join("ours.toml"), edited).unwrap();
    let o = fx.cmd("eval").quiet().config(&missing).out("m3").output();
    assert_refused(&o, "another recipe");
    assert!(stderr(&o).contains("(epochs differ)"), "{}", stderr(&o));
}

/// Regression: a record whose first layer is narrower than class, colour
/// and size (edited by hand) made the appearance width underflow; the
/// binary refuses it, in one line, before anything runs.
#[test]
fn a_record_narrower_than_the_node_attributes_is_refused() {
    let fx = Fixture::new();
    std::fs::create_dir_all(fx.path("models")).unwrap();
    std::fs::copy(repo().join("models/ours.bpk"), fx.path("models/ours.bpk")).unwrap();
    let record = std::fs::read_to_string(repo().join("models/ours.toml")).unwrap();
    assert!(record.contains("node_features = 13"), "{record}");
    fx.write(
        "models/ours.toml",
        &record.replace("node_features = 13", "node_features = 5"),
    );
    let cfg = fx.method_config("w.toml", "ours", "models");
    let out = fx.run(&cfg, "w");
    assert_refused_unwritten(
        &out,
        "is narrower than class, colour and size",
        &fx.path("w"),
    );
}

/// A short run's configuration that trains `coid` for one epoch on run
/// 201 and validates on run 202, with `extra` under `[train]`.
fn one_epoch_of_coid(fx: &Fixture, name: &str, extra: &str) -> std::path::PathBuf {
    fx.config(
        name,
        80.0,
        &format!(
            "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 1\n\
             patience = 1\nmethods = [\"coid\"]\n{extra}\n\
             [pose_noise]\nlevels = [\"gps\"]\n"
        ),
    )
}

/// `coid train` of `config` into `out`, without validation.
fn train_unvalidated(fx: &Fixture, config: &std::path::Path, out: &str) -> std::process::Output {
    fx.cmd("train")
        .quiet()
        .config(config)
        .out(out)
        .args(["--skip-validation"])
        .output()
}

/// `[train] start_from`: training starts from the weights of a models
/// folder. The record names them and their checksum, and before the first
/// step the validation loss is that of those weights (the shipped
/// `coid`'s, trained on the family: below a seeded start's); a folder
/// without them is a clear error.
#[test]
fn training_starts_from_the_weights_start_from_names() {
    let fx = Fixture::new();
    let cfg =
        |name: &str, start: &str| one_epoch_of_coid(&fx, name, &format!("start_from = {start:?}"));
    let shipped = repo().join("models");
    let train = |c: &std::path::Path, out: &str| train_unvalidated(&fx, c, out);
    assert_ok(&train(&cfg("seeded.toml", ""), "seeded"));
    assert_ok(&train(
        &cfg("tuned.toml", shipped.to_str().unwrap()),
        "tuned",
    ));
    let before = |dir: &str| -> f64 {
        let curve = fx.read_text(&format!("{dir}/coid_loss.csv"));
        let row = curve.lines().find(|l| l.starts_with("0,")).unwrap();
        row.rsplit(',').next().unwrap().parse().unwrap()
    };
    let (seeded, tuned) = (before("seeded"), before("tuned"));
    assert!(
        tuned < seeded,
        "validation loss before training: {tuned} vs {seeded}"
    );
    let record = fx.read_text("tuned/coid.toml");
    let bytes = std::fs::read(shipped.join("coid.bpk")).unwrap();
    let fnv = bytes.iter().fold(0xcbf29ce484222325u64, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x100000001b3)
    });
    assert!(
        record.contains(&format!("start_weights_fnv64 = \"{fnv:016x}\"")),
        "{record}"
    );
    assert!(!fx.read_text("seeded/coid.toml").contains("start_from"));
    std::fs::create_dir_all(fx.path("empty")).unwrap();
    let o = train(
        &cfg("nowhere.toml", fx.path("empty").to_str().unwrap()),
        "nowhere",
    );
    assert_refused(&o, "cannot load the weights of 'coid' from");
    assert!(
        stderr(&o).contains("coid.bpk (no such file)"),
        "{}",
        stderr(&o)
    );
}

/// `[train] graph = "complete"`, `consensus_dim` and `edge_scale_m`: the
/// paper's network convolves over every pair of each vehicle's
/// detections, with as many random indicators per consensus step and
/// the edge-length knots as far apart as asked. The record says so (and
/// the default one does not), and the graph is the one trained on: from
/// the same seeded weights the validation loss before the first step
/// differs from the Delaunay graph's. Values out of range are refused.
#[test]
fn a_network_trained_on_the_complete_graph_records_it() {
    let fx = Fixture::new();
    let cfg = |name: &str, network: &str| one_epoch_of_coid(&fx, name, network);
    let train = |c: &std::path::Path, out: &str| train_unvalidated(&fx, c, out);
    assert_ok(&train(&cfg("delaunay.toml", ""), "delaunay"));
    assert_ok(&train(
        &cfg("complete.toml", "graph = \"complete\""),
        "complete",
    ));
    let before = |dir: &str| -> String {
        let curve = fx.read_text(&format!("{dir}/coid_loss.csv"));
        curve
            .lines()
            .find(|l| l.starts_with("0,"))
            .unwrap()
            .to_owned()
    };
    assert_ne!(before("delaunay"), before("complete"));
    let record = fx.read_text("complete/coid.toml");
    let architecture = record.split("[architecture]").nth(1).unwrap();
    assert!(architecture.contains("graph = \"complete\""), "{record}");
    let default = fx.read_text("delaunay/coid.toml");
    assert!(!default.contains("graph ="), "{default}");
    assert!(default.contains("consensus_dim = 32"), "{default}");
    let wide = cfg("wide.toml", "consensus_dim = 8\nedge_scale_m = 30.0");
    assert_ok(&train(&wide, "wide"));
    let record = fx.read_text("wide/coid.toml");
    assert!(record.contains("consensus_dim = 8"), "{record}");
    assert!(record.contains("edge_scale_m = 30.0"), "{record}");
    assert!(default.contains("edge_scale_m = 60.0"), "{default}");
    let o = train(&cfg("knn.toml", "graph = \"knn\""), "knn");
    assert_refused(
        &o,
        "unknown variant `knn`, expected `delaunay` or `complete`",
    );
    let o = train(&cfg("none.toml", "consensus_dim = 0"), "none");
    assert_refused(&o, "train.consensus_dim");
    let o = train(&cfg("short.toml", "edge_scale_m = 0.0"), "short");
    assert_refused(&o, "train.edge_scale_m");
}

/// `[train] node_dropout` and `position_jitter_m`: the paper's network's
/// training pairs are drawn anew each epoch. The record says so (and a
/// default record does not), the training differs from an unperturbed
/// one's from the same seed, the weights are the same on 1 thread or 2
/// (rayon's pool),
/// and values out of range are refused.
#[test]
fn augmented_training_is_recorded_and_deterministic() {
    let fx = Fixture::new();
    let cfg = |name: &str, extra: &str| {
        fx.config(
            name,
            80.0,
            &format!(
                "[train]\ntraffic_seeds = [201]\nvalidation_seeds = [202]\nepochs = 2\n\
                 patience = 2\nmethods = [\"coid\"]\n{extra}\n\
                 [pose_noise]\nlevels = [\"gps\"]\n"
            ),
        )
    };
    let train = |c: &std::path::Path, out: &str, threads: &str| {
        fx.cmd("train")
            .quiet()
            .config(c)
            .out(out)
            .args(["--skip-validation"])
            .env("RAYON_NUM_THREADS", threads)
            .output()
    };
    let augmented = cfg("aug.toml", "node_dropout = 0.2\nposition_jitter_m = 0.5");
    assert_ok(&train(&cfg("plain.toml", ""), "plain", "2"));
    assert_ok(&train(&augmented, "one", "1"));
    assert_ok(&train(&augmented, "two", "2"));
    let weights = |dir: &str| std::fs::read(fx.path(&format!("{dir}/coid.bpk"))).unwrap();
    assert_eq!(weights("one"), weights("two"));
    assert_ne!(weights("one"), weights("plain"));
    let record = fx.read_text("one/coid.toml");
    assert!(record.contains("node_dropout = 0.2"), "{record}");
    assert!(record.contains("position_jitter_m = 0.5"), "{record}");
    assert!(!fx.read_text("plain/coid.toml").contains("node_dropout"));
    let o = train(&cfg("bad.toml", "node_dropout = 1.0"), "bad", "1");
    assert_refused(&o, "train.node_dropout");
    let o = train(&cfg("far.toml", "position_jitter_m = -1.0"), "far", "1");
    assert_refused(&o, "train.position_jitter_m");
}

/// Regression: `coid train --seed 8` alone (the config's `[train] seed`
/// is 7) wrote its weights into `seed-8/` but said "models in <folder>",
/// and `coid eval` then found no record at the folder's root. The last
/// line names the seed's folder and what the root is for.
#[test]
fn training_another_seed_alone_says_where_its_weights_went() {
    let fx = Fixture::new();
    let cfg = one_epoch_of_coid(&fx, "c.toml", "");
    let o = fx
        .cmd("train")
        .quiet()
        .config(&cfg)
        .out("m")
        .args(["--skip-validation", "--seed", "8"])
        .output();
    assert_ok(&o);
    assert!(fx.path("m/seed-8/coid.toml").is_file());
    let said = stderr(&o);
    let seed_dir = std::path::Path::new("m").join("seed-8");
    assert!(
        said.contains(&format!("seed 8's in {}", seed_dir.display())),
        "{said}"
    );
    assert!(said.contains("its root holds [train] seed 7's"), "{said}");
}
