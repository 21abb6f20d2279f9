//! Monte Carlo batches: N independent runs (seeds derived from one master
//! seed) on W worker processes (libsumo allows one simulation per process),
//! resumable, shardable, aggregated into means with 95% confidence
//! intervals.
//!
//! Each run is a child `coid run` writing `<dir>/runs/run-NNNNNN/`, which
//! appears complete or not at all, so a killed batch restarted with the same
//! command does only the missing runs. The aggregate is computed from the
//! run folders in run order, so it is byte-identical whatever the number of
//! workers, the interruptions or the sharding.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use crate::experiments::mean_ci95;
use crate::output::{self, RunRow};
use crate::rng;

/// Which slice of the runs this process does: runs `i` with
/// `i % count == index - 1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 1-based.
    pub index: usize,
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("shard '{s}' is not of the form k/n"))?;
        let index: usize = k
            .trim()
            .parse()
            .map_err(|_| format!("shard '{s}': bad k"))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|_| format!("shard '{s}': bad n"))?;
        if count == 0 || index == 0 || index > count {
            return Err(format!("shard '{s}': need 1 <= k <= n"));
        }
        Ok(Shard { index, count })
    }
}

/// The seeds of run `i` of a batch with master seed `master`.
pub fn run_seeds(master: u64, i: usize) -> (u64, u64) {
    let traffic = rng::key(&[master, i as u64, 1]) % 2_000_000_000;
    let sensor = rng::key(&[master, i as u64, 2]);
    (traffic, sensor)
}

pub fn run_dir(batch_dir: &Path, i: usize) -> PathBuf {
    batch_dir.join("runs").join(format!("run-{i:06}"))
}

/// A run that failed, and why (its last error line).
#[derive(Clone, Debug, PartialEq)]
pub struct Failure {
    pub run: usize,
    pub message: String,
}

/// What to do: the runs of this shard that are not complete yet.
pub fn pending_runs(batch_dir: &Path, runs: usize, shard: Option<Shard>) -> Vec<usize> {
    (0..runs)
        .filter(|i| shard.is_none_or(|s| i % s.count == s.index - 1))
        .filter(|&i| !run_dir(batch_dir, i).join("summary.csv").is_file())
        .collect()
}

/// Runs `pending` on up to `workers` child processes of `exe`; returns the
/// failures. `done(run, ok)` is called as each run ends.
pub fn execute(
    exe: &Path,
    config: &Path,
    batch_dir: &Path,
    master: u64,
    pending: &[usize],
    workers: usize,
    mut done: impl FnMut(usize, bool),
) -> std::io::Result<Vec<Failure>> {
    std::fs::create_dir_all(batch_dir.join("runs"))?;
    let mut queue = pending.iter().copied();
    let mut active: Vec<(usize, Child)> = Vec::new();
    let mut failures = Vec::new();
    loop {
        while active.len() < workers.max(1) {
            let Some(i) = queue.next() else { break };
            let (traffic, sensor) = run_seeds(master, i);
            let child = Command::new(exe)
                .args(["run", "--quiet", "--force", "--config"])
                .arg(config)
                .arg("--out")
                .arg(run_dir(batch_dir, i))
                .args([
                    "--traffic-seed",
                    &traffic.to_string(),
                    "--sensor-seed",
                    &sensor.to_string(),
                ])
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()?;
            active.push((i, child));
        }
        if active.is_empty() {
            break;
        }
        // Wait for whichever child ends first (polling: the children run for
        // seconds, a few milliseconds of latency do not matter).
        let mut finished = None;
        while finished.is_none() {
            for (k, (_, child)) in active.iter_mut().enumerate() {
                if let Some(status) = child.try_wait()? {
                    finished = Some((k, status));
                    break;
                }
            }
            if finished.is_none() {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
        }
        let (k, status) = finished.expect("set above");
        let (i, mut child) = active.swap_remove(k);
        let ok = status.success() && run_dir(batch_dir, i).join("summary.csv").is_file();
        if !ok {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = e.read_to_string(&mut err);
            }
            let message = err
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("the run exited without a message")
                .trim()
                .to_owned();
            failures.push(Failure { run: i, message });
        }
        done(i, ok);
    }
    failures.sort_by_key(|f| f.run);
    Ok(failures)
}

/// One line of a batch's `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct AggregateRow {
    pub method: String,
    pub pose_noise: String,
    pub fusion: String,
    pub n_runs: usize,
    pub n_instances: u64,
    /// (mean over runs, 95% CI half-width) of each metric.
    pub precision: (f64, f64),
    pub recall: (f64, f64),
    pub f1: (f64, f64),
    pub de_single_m: (f64, f64),
    pub de_fused_m: (f64, f64),
}

/// Aggregates the completed runs found in `run_dirs` (any order; they are
/// sorted by name so the result does not depend on it).
pub fn aggregate(run_dirs: &[PathBuf]) -> Result<Vec<AggregateRow>, output::OutputError> {
    let mut dirs = run_dirs.to_vec();
    dirs.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    let mut order: Vec<(String, String, String)> = Vec::new();
    let mut groups: BTreeMap<(String, String, String), Vec<RunRow>> = BTreeMap::new();
    for d in &dirs {
        for row in output::read_run_summary(&d.join("summary.csv"))? {
            let key = (
                row.method.clone(),
                row.pose_noise.clone(),
                row.fusion.clone(),
            );
            if !groups.contains_key(&key) {
                order.push(key.clone());
            }
            groups.entry(key).or_default().push(row);
        }
    }
    Ok(order
        .into_iter()
        .map(|key| {
            let rows = &groups[&key];
            let stat = |f: fn(&RunRow) -> f64| mean_ci95(&rows.iter().map(f).collect::<Vec<_>>());
            AggregateRow {
                method: key.0.clone(),
                pose_noise: key.1.clone(),
                fusion: key.2.clone(),
                n_runs: rows.len(),
                n_instances: rows.iter().map(|r| r.n_instances).sum(),
                precision: stat(|r| r.precision),
                recall: stat(|r| r.recall),
                f1: stat(|r| r.f1),
                de_single_m: stat(|r| r.de_single_m),
                de_fused_m: stat(|r| r.de_fused_m),
            }
        })
        .collect())
}

/// The completed run folders under `<batch_dir>/runs`.
pub fn completed_runs(batch_dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let runs = batch_dir.join("runs");
    if !runs.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(runs)? {
        let p = e?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.starts_with("run-") && p.join("summary.csv").is_file() {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_partition_the_runs() {
        assert_eq!("2/3".parse::<Shard>(), Ok(Shard { index: 2, count: 3 }));
        assert!("0/3".parse::<Shard>().is_err());
        assert!("4/3".parse::<Shard>().is_err());
        assert!("x".parse::<Shard>().is_err());
        let dir = tempfile::tempdir().unwrap();
        let mut all: Vec<usize> = (1..=3)
            .flat_map(|k| pending_runs(dir.path(), 10, Some(Shard { index: k, count: 3 })))
            .collect();
        all.sort();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
    }

    #[test]
    fn run_seeds_differ_per_run_and_master() {
        assert_ne!(run_seeds(1, 0), run_seeds(1, 1));
        assert_ne!(run_seeds(1, 0), run_seeds(2, 0));
        assert_eq!(run_seeds(5, 3), run_seeds(5, 3));
        assert!(run_seeds(9, 9).0 < 2_000_000_000);
    }
}
