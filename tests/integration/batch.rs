//! `coid batch` and `coid merge`: workers, resumes, shards, failing runs.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// A fast batch config: short runs, cheap methods.
fn fast_config(fx: &Fixture, sumocfg: &Path) -> PathBuf {
    let scenario = scenario_toml(sumocfg, "C");
    fx.write(
        "b.toml",
        &format!("{scenario}end_s = 75\n[matching]\nmethods = [\"gps-hungarian\", \"oracle\"]\n"),
    )
}

/// `coid batch` of `runs` runs on `workers` workers into `out`, and
/// `extra` arguments.
fn batch(fx: &Fixture, cfg: &Path, runs: &str, workers: &str, out: &str, extra: &[&str]) -> Output {
    batch_cmd(fx, cfg, runs, workers, out).args(extra).output()
}

fn batch_cmd<'a>(fx: &'a Fixture, cfg: &Path, runs: &str, workers: &str, out: &str) -> Cmd<'a> {
    let cmd = fx.cmd("batch").quiet().config(cfg);
    cmd.args(["--runs", runs, "--workers", workers]).out(out)
}

fn bytes(fx: &Fixture, dir: &str) -> Vec<u8> {
    fx.read(&format!("{dir}/summary.csv"))
}

/// Starts `coid batch` of `runs` runs on one worker into `out` without
/// waiting for it.
fn spawn_batch(fx: &Fixture, cfg: &Path, runs: &str, out: &str) -> std::process::Child {
    batch_cmd(fx, cfg, runs, "1", out).spawn()
}

/// Waits until the first run of the batch in `out` is complete.
fn wait_for_first_run(fx: &Fixture, out: &str) {
    let first = fx.path(&format!("{out}/runs/run-000000/summary.csv"));
    let deadline = Instant::now() + Duration::from_secs(60);
    wait_until(deadline, "first run never finished", || first.is_file());
}

#[test]
fn one_and_two_workers_give_identical_aggregates_with_intervals() {
    let fx = Fixture::new();
    let cfg = fast_config(&fx, &shipped_sumocfg());
    assert_ok(&batch(&fx, &cfg, "4", "1", "w1", &[]));
    assert_ok(&batch(&fx, &cfg, "4", "2", "w2", &[]));
    assert_eq!(bytes(&fx, "w1"), bytes(&fx, "w2"));
    let s = read_csv(&fx.path("w1/summary.csv"));
    for c in ["de_fused_m_ci95", "f1_ci95", "n_runs"] {
        assert!(s.column(c).is_ok(), "{c} missing");
    }
    for i in 0..4 {
        assert!(
            fx.path(&format!("w1/runs/run-{i:06}/summary.csv"))
                .is_file()
        );
    }
}

#[test]
fn a_killed_batch_resumes_to_the_same_bytes() {
    let fx = Fixture::new();
    let cfg = fast_config(&fx, &shipped_sumocfg());
    assert_ok(&batch(&fx, &cfg, "5", "2", "whole", &[]));
    let mut child = spawn_batch(&fx, &cfg, "5", "killed");
    // Kill it once the first run is complete, mid-batch.
    wait_for_first_run(&fx, "killed");
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(!fx.path("killed/summary.csv").exists() || bytes(&fx, "killed") != bytes(&fx, "whole"));
    // Only the missing runs run again: the finished one is left alone.
    let finished = fx.path("killed/runs/run-000000/summary.csv");
    let before = modified(&finished);
    assert_ok(&batch(&fx, &cfg, "5", "2", "killed", &[]));
    assert_eq!(modified(&finished), before);
    assert_eq!(bytes(&fx, "killed"), bytes(&fx, "whole"));
}

/// Killing `coid batch` ends its workers too (no orphans).
#[test]
fn the_workers_of_a_killed_batch_end_with_it() {
    let (fx, cfg) = Fixture::with_config(200.0, "[connected]\npenetration = 0.3\n");
    let batch = batch_cmd(&fx, &cfg, "4", "2", "b");
    let mut parent = batch.command().spawn().unwrap();
    let children_of = |pid: u32| -> Vec<u32> {
        let tasks = format!("/proc/{pid}/task");
        std::fs::read_dir(tasks)
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|t| std::fs::read_to_string(t.path().join("children")).ok())
            .flat_map(|c| {
                c.split_whitespace()
                    .filter_map(|p| p.parse().ok())
                    .collect::<Vec<u32>>()
            })
            .collect()
    };
    let started = Instant::now();
    let mut workers = Vec::new();
    wait_until(
        started + Duration::from_secs(60),
        "no workers started",
        || {
            workers = children_of(parent.id());
            workers.len() == 2
        },
    );
    parent.kill().unwrap(); // SIGKILL: no chance to clean up
    parent.wait().unwrap();
    let gone = |pid: &u32| {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map_or(true, |s| s.split_whitespace().nth(2) == Some("Z"))
    };
    let orphans = format!("orphaned workers {workers:?}");
    wait_until(started + Duration::from_secs(90), &orphans, || {
        workers.iter().all(gone)
    });
}

/// A batch is what its configuration says, not where it lies: a
/// resume after an edit is refused, shards of two different batches
/// do not merge, and the same config at another path resumes and
/// merges.
#[test]
fn a_batch_is_identified_by_content_not_by_path() {
    let fx = Fixture::new();
    let cfg = fast_config(&fx, &shipped_sumocfg());
    let text = fx.read_text("b.toml");
    assert_ok(&batch(&fx, &cfg, "2", "1", "b", &["--shard", "1/2"]));
    // The same config at another path: the other shard, and a resume.
    std::fs::create_dir_all(fx.path("elsewhere")).unwrap();
    let moved = fx.write("elsewhere/b.toml", &text);
    assert_ok(&batch(&fx, &moved, "2", "1", "b2", &["--shard", "2/2"]));
    assert_ok(&batch(&fx, &moved, "2", "1", "b", &["--shard", "1/2"]));
    assert_ok(&fx.coid(&["merge", "b", "b2", "--out", "merged"]));
    // An edit (one setting) makes another batch.
    let edited = fx.write(
        "edited.toml",
        &format!("{text}[sensor]\ncolour_sigma = 0.07\n"),
    );
    let out = batch(&fx, &edited, "2", "1", "b", &["--shard", "1/2"]);
    assert_refused(&out, "has changed since");
    assert_ok(&batch(&fx, &edited, "2", "1", "e2", &["--shard", "2/2"]));
    let out = fx.coid(&["merge", "b", "e2", "--out", "mixed"]);
    assert_refused_unwritten(&out, "different batch", &fx.path("mixed"));
}

/// A resume checks every run folder: a summary cut short or a missing
/// objects.parquet is run again, and the aggregate is as if nothing
/// happened.
#[test]
fn a_resumed_batch_reruns_damaged_runs() {
    let fx = Fixture::new();
    let cfg = fast_config(&fx, &shipped_sumocfg());
    assert_ok(&batch(&fx, &cfg, "3", "2", "whole", &[]));
    assert_ok(&batch(&fx, &cfg, "3", "2", "damaged", &[]));
    let run = |i: usize, f: &str| fx.path(&format!("damaged/runs/run-{i:06}/{f}"));
    let summary = std::fs::read_to_string(run(0, "summary.csv")).unwrap();
    std::fs::write(run(0, "summary.csv"), &summary[..summary.len() * 2 / 3]).unwrap();
    std::fs::remove_file(run(1, "objects.parquet")).unwrap();
    let untouched = modified(&run(2, "summary.csv"));
    assert_ok(&batch(&fx, &cfg, "3", "2", "damaged", &[]));
    assert_eq!(bytes(&fx, "damaged"), bytes(&fx, "whole"));
    assert!(run(1, "objects.parquet").is_file());
    assert_eq!(modified(&run(2, "summary.csv")), untouched);
}

#[test]
fn merged_shards_equal_the_unsharded_batch() {
    let fx = Fixture::new();
    let cfg = fast_config(&fx, &shipped_sumocfg());
    assert_ok(&batch(&fx, &cfg, "5", "2", "all", &[]));
    assert_ok(&batch(&fx, &cfg, "5", "1", "s1", &["--shard", "1/2"]));
    assert_ok(&batch(&fx, &cfg, "5", "1", "s2", &["--shard", "2/2"]));
    assert_ok(&fx.coid(&["merge", "s1", "s2", "--out", "merged"]));
    assert_eq!(bytes(&fx, "merged"), bytes(&fx, "all"));
    assert_eq!(fx.read("merged/summary.md"), fx.read("all/summary.md"));
}

#[test]
fn failing_runs_are_reported_and_do_not_poison_the_aggregate() {
    let fx = Fixture::new();
    // A private copy of the scenario, removed once the first run is done.
    let scen = fx.path("scenario");
    std::fs::create_dir_all(&scen).unwrap();
    for e in std::fs::read_dir(repo().join("sumo_nets/intersection")).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, scen.join(p.file_name().unwrap())).unwrap();
    }
    let cfg = fast_config(&fx, &scen.join("intersection.sumocfg"));
    let child = spawn_batch(&fx, &cfg, "4", "f");
    wait_for_first_run(&fx, "f");
    std::fs::remove_file(scen.join("intersection.sumocfg")).unwrap();
    let out = child.wait_with_output().unwrap();
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("failed") && err.contains("no such file"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let s = read_csv(&fx.path("f/summary.csv"));
    let n_runs = f64s(&s, "n_runs");
    assert!(
        n_runs.iter().all(|&n| (1.0..4.0).contains(&n)),
        "{n_runs:?}"
    );
    assert!(f64s(&s, "f1").iter().all(|v| v.is_finite()));
}
