//! `coid scenarios`: deterministic generation, and every generated scenario
//! runs.

use crate::util::*;
use std::path::Path;

/// Every file of a folder, by name.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect();
    out.sort();
    out
}

/// The same seed gives the same bytes (the SUMO net included), another
/// seed other scenarios, and every generated scenario runs as its
/// folder's config says, with only the simulated time shortened.
#[test]
fn generation_is_deterministic_and_every_scenario_runs() {
    let fx = Fixture::new();
    let generate = |count: &str, seed: &str, out: &str| {
        let cmd = fx.cmd("scenarios").quiet();
        cmd.args(["--count", count, "--seed", seed])
            .out(out)
            .output()
    };
    for out in ["a", "b"] {
        assert_ok(&generate("3", "4", out));
    }
    assert_ok(&generate("1", "5", "c"));
    for s in ["s000", "s001", "s002"] {
        let (a, b) = (files(&fx.path("a").join(s)), files(&fx.path("b").join(s)));
        let names: Vec<&str> = a.iter().map(|f| f.0.as_str()).collect();
        assert!(names.contains(&"net.net.xml") && names.contains(&"coid.toml"));
        assert_eq!(a, b, "{s} differs between two generations");
    }
    assert_ne!(files(&fx.path("a/s000")), files(&fx.path("c/s000")));
    // Again into an existing folder: refused without --force.
    assert_refused(&generate("1", "4", "a"), "exists");
    let mut instances = 0.0;
    for s in ["s000", "s001", "s002"] {
        let dir = fx.path("a").join(s);
        let own = std::fs::read_to_string(dir.join("coid.toml")).unwrap();
        let cfg = dir.join("short.toml");
        // Shorter, with more connected vehicles, so that 60 s give
        // instances.
        let short = own
            .replace("end_s = 150.0", "end_s = 60.0")
            .replace("penetration = 0.1", "penetration = 0.5")
            + "[matching]\nmethods = [\"oracle\", \"gps-hungarian\"]\n";
        std::fs::write(&cfg, short).unwrap();
        let out = format!("run-{s}");
        assert_ok(&fx.run(&cfg, &out));
        let summary = read_csv(&fx.path(&out).join("summary.csv"));
        // A run without instances has no rows.
        instances += f64s(&summary, "n_instances")
            .first()
            .copied()
            .unwrap_or(0.0);
    }
    assert!(instances > 0.0, "no instance in three generated scenarios");
}
