//! ARCHITECTURE.md's invariants, checked on the source tree: the layering
//! of modules (arrows point down) and which module alone touches pyo3,
//! polars, burn, the file system, child processes and the ground truth.
//! Test modules (`#[cfg(test)]` and after) are not checked: tests may
//! build whatever fixtures they need.

use std::path::{Path, PathBuf};

/// Top-level modules by layer: a module may use only modules of lower
/// layers (and its own submodules).
const LAYERS: &[&[&str]] = &[
    &["geometry", "rng", "label"],
    &["traffic", "scenarios"],
    &["bridge", "sensor", "graph", "fusion"],
    &["matching"],
    &["evaluate"],
    &["config"],
    &["report"],
    &["tables", "render", "io"],
    &["pipeline"],
    &["experiments", "batch"],
    &["cli"],
];

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `src/`, as (path relative to `src/`, code before
/// its test module).
fn sources() -> Vec<(String, String)> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(&src(), &mut files);
    files.sort();
    files
        .into_iter()
        .filter(|p| !p.ends_with("matching/testkit.rs"))
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            let code = match text.find("#[cfg(test)]\nmod tests") {
                Some(k) => text[..k].to_owned(),
                None => text,
            };
            let rel = p
                .strip_prefix(src())
                .unwrap()
                .to_string_lossy()
                .into_owned();
            (rel, code)
        })
        .collect()
}

/// The top-level module a file belongs to (`matching/deep/model.rs` ->
/// `matching`).
fn module_of(rel: &str) -> String {
    rel.split('/')
        .next()
        .unwrap()
        .trim_end_matches(".rs")
        .to_owned()
}

fn layer(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

/// The top-level modules a file names through `crate::` paths (in `use`
/// lines and inline).
fn crate_deps(code: &str) -> Vec<String> {
    let mut deps = Vec::new();
    for line in code.lines().filter(|l| !l.trim_start().starts_with("//")) {
        let mut rest = line;
        while let Some(k) = rest.find("crate::") {
            rest = &rest[k + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            // `crate::label_enum!` is the label module's macro.
            let name = if name == "label_enum" {
                "label".into()
            } else {
                name
            };
            if !name.is_empty() && !deps.contains(&name) {
                deps.push(name);
            }
        }
    }
    deps
}

#[test]
fn arrows_point_down() {
    let mut wrong = Vec::new();
    for (rel, code) in sources() {
        let module = module_of(&rel);
        if module == "lib" || module == "main" {
            continue;
        }
        let Some(mine) = layer(&module) else {
            wrong.push(format!("{rel}: module `{module}` has no layer in LAYERS"));
            continue;
        };
        for dep in crate_deps(&code) {
            if dep == module {
                continue;
            }
            match layer(&dep) {
                Some(l) if l < mine => {}
                _ => wrong.push(format!("{rel} ({module}) uses crate::{dep}")),
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "upward or sideways imports:\n{}",
        wrong.join("\n")
    );
}

/// Whether `line` contains `needle`; a needle ending in `$` must end a
/// word there (`.truth$` matches `.truth` and `.truth.x`, not `.truth_m`).
fn matches(line: &str, needle: &str) -> bool {
    let Some(word) = needle.strip_suffix('$') else {
        return line.contains(needle);
    };
    line.match_indices(word).any(|(k, _)| {
        line[k + word.len()..]
            .chars()
            .next()
            .is_none_or(|c| !(c.is_alphanumeric() || c == '_'))
    })
}

/// Files (relative to `src/`) whose code matches `needle`.
fn files_with(needle: &str) -> Vec<String> {
    sources()
        .into_iter()
        .filter(|(_, code)| {
            code.lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .any(|l| matches(l, needle))
        })
        .map(|(rel, _)| rel)
        .collect()
}

/// Every file using any of `needles` is one of `allowed`.
fn only_in(needles: &[&str], allowed: &[&str]) {
    for needle in needles {
        let offenders: Vec<String> = files_with(needle)
            .into_iter()
            .filter(|f| !allowed.contains(&f.as_str()))
            .collect();
        assert!(
            offenders.is_empty(),
            "`{needle}` outside {allowed:?}: {offenders:?}"
        );
    }
}

#[test]
fn only_the_bridge_touches_python() {
    only_in(&["pyo3", "Python::"], &["bridge.rs"]);
}

#[test]
fn only_io_frames_touches_polars() {
    only_in(&["polars"], &["io/frames.rs", "io/mod.rs"]);
    // io/mod.rs names polars' error type only.
    let io_mod = std::fs::read_to_string(src().join("io/mod.rs")).unwrap();
    let uses: Vec<&str> = io_mod
        .lines()
        .filter(|l| l.contains("polars") && !l.trim_start().starts_with("//"))
        .collect();
    assert!(
        uses.iter().all(|l| l.contains("PolarsError")),
        "io/mod.rs: {uses:?}"
    );
}

#[test]
fn only_the_deep_matcher_sees_tensors() {
    only_in(
        &["burn::", "Tensor<"],
        &[
            "matching/deep/mod.rs",
            "matching/deep/model.rs",
            "matching/deep/train.rs",
        ],
    );
}

#[test]
fn only_io_writes_files_and_only_batch_and_bridge_start_processes() {
    only_in(
        &[
            "std::fs::write",
            "File::create",
            "create_dir",
            "std::fs::rename",
            "remove_dir",
            "tempfile",
            "std::fs::copy",
        ],
        &["io/mod.rs", "io/frames.rs", "bridge.rs"],
    );
    // The bridge only removes its own capture of SUMO's stderr.
    let bridge = std::fs::read_to_string(src().join("bridge.rs")).unwrap();
    assert!(!bridge.contains("std::fs::write") && !bridge.contains("create_dir"));
    // Reading: the config file, weights, batch folders, the venv.
    only_in(
        &["std::fs::read", "File::open", "read_dir"],
        &["config.rs", "io/mod.rs", "io/frames.rs", "bridge.rs"],
    );
    // Batch starts its workers; the bridge runs SUMO's netconvert.
    only_in(
        &["std::process::Command", "process::{"],
        &["batch.rs", "bridge.rs"],
    );
}

#[test]
fn every_random_draw_comes_from_a_named_stream() {
    only_in(
        &[
            "thread_rng",
            "rand::rng()",
            "from_entropy",
            "from_os_rng",
            "Tensor::random",
            "Distribution::Uniform",
            "Distribution::Normal",
            ".seed(",
        ],
        &[],
    );
    // Streams are made in one place.
    only_in(&["seed_from_u64", "ChaCha8Rng::from"], &["rng.rs"]);
}

#[test]
fn matchers_cannot_reach_the_ground_truth() {
    // The truth types are named only by the sensor (which makes them), the
    // oracle, the evaluation, the tables and pictures that score and draw
    // it, and the pipeline and render command that pass it along.
    only_in(
        &["ObservationTruth", "DetectionTruth", ".truth$"],
        &[
            "sensor.rs",
            "matching/oracle.rs",
            "evaluate/mod.rs",
            "evaluate/map.rs",
            "tables.rs",
            "render.rs",
            "pipeline.rs",
            "experiments.rs",
            "cli/render.rs",
        ],
    );
    // What a matcher receives holds no truth.
    let matching = std::fs::read_to_string(src().join("matching/mod.rs")).unwrap();
    let view = &matching[matching.find("pub struct MatchView").unwrap()..];
    let view = &view[..view.find('}').unwrap()];
    assert!(
        !view.contains("truth") && !view.contains("Sensed"),
        "{view}"
    );
}

#[test]
fn main_is_thin() {
    let main = std::fs::read_to_string(src().join("main.rs")).unwrap();
    assert!(
        main.lines().count() < 100,
        "main.rs has {} lines",
        main.lines().count()
    );
}
