//! ARCHITECTURE.md's invariants, checked on the source tree: the layering
//! of modules (arrows point down) and which module alone touches pyo3,
//! polars, burn, the file system, child processes and the ground truth.
//! Test modules (`#[cfg(test)]` and after) are not checked: tests may
//! build whatever fixtures they need.

use std::path::{Path, PathBuf};

/// Top-level modules by layer, as ARCHITECTURE.md's layer table states
/// them (`| 3 | \`matching\` |` rows): a module may use only modules of
/// lower layers (and its own submodules).
fn layers() -> Vec<Vec<String>> {
    let text = architecture_md();
    let mut rows: Vec<(usize, Vec<String>)> = text
        .lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let n = cells.get(1)?.parse::<usize>().ok()?;
            let names = cells.get(2)?;
            let modules = names
                .split('`')
                .skip(1)
                .step_by(2)
                .map(str::to_owned)
                .collect();
            Some((n, modules))
        })
        .collect();
    rows.sort();
    assert!(rows.len() > 5, "no layer table in ARCHITECTURE.md");
    for (k, (n, _)) in rows.iter().enumerate() {
        assert_eq!(
            *n, k,
            "ARCHITECTURE.md's layers are not numbered 0, 1, 2, ..."
        );
    }
    rows.into_iter().map(|(_, m)| m).collect()
}

fn architecture_md() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("ARCHITECTURE.md")).unwrap()
}

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
    let tests = test_module_files(&files);
    files
        .into_iter()
        .filter(|p| !tests.contains(p))
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            // Up to the inline test module: a `#[cfg(test)] mod tests;`
            // declaration may stand before the file's code.
            let code = match text.find("#[cfg(test)]\nmod tests {") {
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

/// The files of modules declared `#[cfg(test)] mod name;` (test code
/// only, like a file's own `mod tests { ... }`).
fn test_module_files(files: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(f).unwrap();
        let dir = match f.file_stem().and_then(|s| s.to_str()) {
            Some("mod" | "lib" | "main") => f.parent().unwrap().to_owned(),
            _ => f.with_extension(""),
        };
        let mut rest = text.as_str();
        while let Some(k) = rest.find("#[cfg(test)]") {
            rest = &rest[k + "#[cfg(test)]".len()..];
            let decl = rest.trim_start();
            let decl = decl.strip_prefix("pub(crate) ").unwrap_or(decl);
            if let Some((name, _)) = decl.strip_prefix("mod ").and_then(|d| d.split_once(';'))
                && !name.contains('{')
            {
                out.push(dir.join(format!("{}.rs", name.trim())));
            }
        }
    }
    out
}

/// The top-level module a file belongs to (`matching/deep/network.rs` ->
/// `matching`).
fn module_of(rel: &str) -> String {
    rel.split('/')
        .next()
        .unwrap()
        .trim_end_matches(".rs")
        .to_owned()
}

fn layer(layers: &[Vec<String>], module: &str) -> Option<usize> {
    layers.iter().position(|l| l.iter().any(|m| m == module))
}

/// The `crate::` dependencies found so far, in a file `depth` modules
/// below the crate root (`io/folder.rs`: 2), so that `super::` paths that
/// reach the root are counted too.
#[derive(Default)]
struct Deps {
    found: std::collections::BTreeSet<String>,
    depth: usize,
}

/// Where a path's next segment is, seen from the file.
#[derive(Clone, Copy)]
enum At {
    /// Not a crate path.
    Outside,
    /// The crate root: the next segment is a top-level module.
    Root,
    /// `k` modules below the root: inside the file's own module.
    Below(usize),
}

fn is_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("cfg")
            && a.meta
                .require_list()
                .is_ok_and(|l| l.tokens.to_string().split_whitespace().any(|t| t == "test"))
    })
}

impl Deps {
    fn add(&mut self, name: &str) {
        // `crate::label_enum!` is the label module's macro.
        let name = if name == "label_enum" { "label" } else { name };
        self.found.insert(name.to_owned());
    }

    /// Where a path starting with `first` leads, from `at`.
    fn step(&self, at: At, first: &str) -> Option<At> {
        match (at, first) {
            (At::Outside, "crate" | "coid_sim") => Some(At::Root),
            (At::Outside, "super") => Some(self.up(self.depth)),
            (At::Below(k), "super") => Some(self.up(k)),
            _ => None,
        }
    }

    fn up(&self, k: usize) -> At {
        match k.saturating_sub(1) {
            0 => At::Root,
            j => At::Below(j),
        }
    }

    fn tree(&mut self, t: &syn::UseTree, at: At) {
        match (t, at) {
            (syn::UseTree::Path(p), _) => {
                if let Some(next) = self.step(at, &p.ident.to_string()) {
                    self.tree(&p.tree, next);
                } else if let At::Root = at {
                    self.add(&p.ident.to_string());
                }
            }
            (syn::UseTree::Name(n), At::Root) => self.add(&n.ident.to_string()),
            (syn::UseTree::Rename(r), At::Root) => self.add(&r.ident.to_string()),
            (syn::UseTree::Group(g), _) => {
                for t in &g.items {
                    self.tree(t, at);
                }
            }
            _ => {}
        }
    }
}

impl<'ast> syn::visit::Visit<'ast> for Deps {
    fn visit_item(&mut self, i: &'ast syn::Item) {
        let attrs = match i {
            syn::Item::Mod(m) => &m.attrs,
            syn::Item::Fn(f) => &f.attrs,
            syn::Item::Impl(m) => &m.attrs,
            syn::Item::Use(u) => &u.attrs,
            syn::Item::Struct(s) => &s.attrs,
            syn::Item::Const(c) => &c.attrs,
            _ => return syn::visit::visit_item(self, i),
        };
        if is_test(attrs) {
            return;
        }
        // An inline `mod x { ... }` is one module deeper.
        let inline = matches!(i, syn::Item::Mod(m) if m.content.is_some());
        self.depth += usize::from(inline);
        syn::visit::visit_item(self, i);
        self.depth -= usize::from(inline);
    }

    fn visit_impl_item_fn(&mut self, f: &'ast syn::ImplItemFn) {
        if !is_test(&f.attrs) {
            syn::visit::visit_impl_item_fn(self, f);
        }
    }

    fn visit_item_use(&mut self, u: &'ast syn::ItemUse) {
        self.tree(&u.tree, At::Outside);
    }

    fn visit_path(&mut self, p: &'ast syn::Path) {
        let mut at = At::Outside;
        for seg in &p.segments {
            match self.step(at, &seg.ident.to_string()) {
                Some(next) => at = next,
                None => {
                    if let At::Root = at {
                        self.add(&seg.ident.to_string());
                    }
                    break;
                }
            }
        }
        syn::visit::visit_path(self, p);
    }

    fn visit_macro(&mut self, m: &'ast syn::Macro) {
        self.visit_path(&m.path);
        // Paths inside a macro's tokens (format!, assert!, ...).
        let tokens: Vec<String> = m
            .tokens
            .clone()
            .into_iter()
            .map(|t| t.to_string())
            .collect();
        for w in tokens.windows(4) {
            if (w[0] == "crate" || w[0] == "coid_sim") && w[1] == ":" && w[2] == ":" {
                self.add(&w[3]);
            }
        }
    }
}

/// The top-level modules a file (`rel`, under `src/`) names through
/// `crate::` paths, or `super::` paths that reach the crate root (in `use`
/// trees, groups included, in paths inline and in macro paths), outside
/// items marked `#[cfg(test)]`; `coid_sim::` counts too (the binary's
/// `main.rs` names the library that way).
fn crate_deps(rel: &str, code: &str) -> Vec<String> {
    use syn::visit::Visit;
    let file = syn::parse_file(code).unwrap_or_else(|e| panic!("cannot parse: {e}"));
    let parts: Vec<&str> = rel.trim_end_matches(".rs").split('/').collect();
    let depth = match parts.last() {
        Some(&"mod") => parts.len() - 1,
        Some(&"lib") | Some(&"main") => 0,
        _ => parts.len(),
    };
    let mut deps = Deps {
        depth,
        ..Deps::default()
    };
    deps.visit_file(&file);
    deps.found.into_iter().collect()
}

/// The code map's entries of ARCHITECTURE.md: (path under `src/`, the
/// modules its "Uses:" line lists).
fn code_map() -> Vec<(String, Vec<String>)> {
    let text = architecture_md();
    let mut out = Vec::new();
    for entry in text.split("\n\n").filter(|p| p.starts_with("**`src/")) {
        let path = entry["**`src/".len()..]
            .split('`')
            .next()
            .unwrap()
            .to_owned();
        let flat = entry.split_whitespace().collect::<Vec<_>>().join(" ");
        let uses = flat
            .rsplit_once("Uses: ")
            .unwrap_or_else(|| panic!("the entry of src/{path} has no Uses: line"))
            .1;
        let uses = &uses[..uses.find('.').unwrap_or(uses.len())];
        let names = uses
            .split('`')
            .skip(1)
            .step_by(2)
            .map(str::to_owned)
            .collect();
        out.push((path, names));
    }
    out
}

#[test]
fn the_code_map_says_what_each_module_uses() {
    let map = code_map();
    let sources = sources();
    let mut wrong = Vec::new();
    for (path, listed) in &map {
        // The files of this entry: the most specific entry covers a file.
        let covers = |rel: &str, p: &str| rel == p || (p.ends_with('/') && rel.starts_with(p));
        let mut used = std::collections::BTreeSet::new();
        for (rel, code) in &sources {
            let best = map
                .iter()
                .filter(|(p, _)| covers(rel, p))
                .max_by_key(|(p, _)| p.len());
            if best.is_some_and(|(p, _)| p == path) {
                used.extend(crate_deps(rel, code));
            }
        }
        used.remove(&module_of(path));
        let listed: std::collections::BTreeSet<String> = listed.iter().cloned().collect();
        if used != listed {
            wrong.push(format!(
                "src/{path}: the code uses {used:?}, the map says {listed:?}"
            ));
        }
    }
    assert!(
        wrong.is_empty(),
        "ARCHITECTURE.md's Uses: lines are wrong:\n{}",
        wrong.join("\n")
    );
    // Every top-level module has an entry.
    for (rel, _) in &sources {
        let m = module_of(rel);
        if m != "lib" {
            assert!(
                map.iter().any(|(p, _)| module_of(p) == m),
                "src/{rel}: no entry in ARCHITECTURE.md's code map"
            );
        }
    }
}

#[test]
fn arrows_point_down() {
    let layers = layers();
    let mut wrong = Vec::new();
    for (rel, code) in sources() {
        let module = module_of(&rel);
        if module == "lib" || module == "main" {
            continue;
        }
        let Some(mine) = layer(&layers, &module) else {
            wrong.push(format!(
                "{rel}: module `{module}` has no layer in ARCHITECTURE.md"
            ));
            continue;
        };
        for dep in crate_deps(&rel, &code) {
            if dep == module {
                continue;
            }
            match layer(&layers, &dep) {
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
/// Fails when a file outside `allowed` (paths under `src/`; one ending in
/// `/` allows a whole folder) contains one of `needles`.
fn only_in(needles: &[&str], allowed: &[&str]) {
    let allows = |f: &str| {
        allowed
            .iter()
            .any(|a| *a == f || (a.ends_with('/') && f.starts_with(a)))
    };
    for needle in needles {
        let offenders: Vec<String> = files_with(needle)
            .into_iter()
            .filter(|f| !allows(f))
            .collect();
        assert!(
            offenders.is_empty(),
            "`{needle}` outside {allowed:?}: {offenders:?}"
        );
    }
}

#[test]
fn only_the_bridge_touches_python() {
    only_in(&["pyo3", "Python::"], &["bridge/"]);
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
    // Training: its modules, the trainer and the tensor reference of
    // inference; the building blocks, the MC shell and the networks'
    // inference see none.
    only_in(&["burn::", "Tensor<"], &["matching/deep/train/"]);
}

/// The deep matchers' layers: the building blocks and the networks'
/// inference never name training (`matching/deep/train/`); only the
/// facade (`deep/mod.rs`, which hands out both) and training itself do.
#[test]
fn inference_never_imports_training() {
    let inference = |f: &str| {
        f.starts_with("matching/deep/")
            && !f.starts_with("matching/deep/train/")
            && f != "matching/deep/mod.rs"
    };
    for (rel, code) in sources().into_iter().filter(|(f, _)| inference(f)) {
        let named: Vec<&str> = code
            .lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .filter(|l| matches(l, "train::") || matches(l, "train$") && l.contains("use "))
            .collect();
        assert!(
            named.is_empty(),
            "src/{rel} (inference) names training: {named:?}"
        );
    }
}

/// The deep matchers' modules and their layer: building blocks (0),
/// the networks' inference (1), training (2).
const DEEP_LAYERS: [(&str, usize); 10] = [
    ("features", 0),
    ("decision", 0),
    ("kernels", 0),
    ("arch", 0),
    ("params", 0),
    ("cost", 0),
    ("mc", 0),
    ("ours", 1),
    ("published", 1),
    ("train", 2),
];

/// Inside `matching/deep/`, a module names only modules of lower layers
/// or of its own ([`DEEP_LAYERS`]), and the building blocks name one
/// another without a circle.
#[test]
fn the_deep_matchers_layers_point_down_without_circles() {
    let module_of = |rel: &str| -> Option<&'static str> {
        let rest = rel.strip_prefix("matching/deep/")?;
        let first = rest.split('/').next()?.trim_end_matches(".rs");
        DEEP_LAYERS
            .iter()
            .find(|(m, _)| *m == first)
            .map(|(m, _)| *m)
    };
    let layer = |m: &str| DEEP_LAYERS.iter().find(|(n, _)| *n == m).map(|(_, l)| *l);
    let mut edges: Vec<(&str, &str)> = Vec::new();
    for (rel, code) in sources() {
        let Some(from) = module_of(&rel) else {
            continue;
        };
        for line in code.lines().filter(|l| !l.trim_start().starts_with("//")) {
            for (to, _) in DEEP_LAYERS {
                let named = ["deep::", "super::", "super::super::"].iter().any(|p| {
                    matches(line, &format!("{p}{to}::")) || matches(line, &format!("{p}{to}$"))
                });
                if named && to != from && !edges.contains(&(from, to)) {
                    edges.push((from, to));
                }
            }
        }
    }
    for &(from, to) in &edges {
        assert!(
            layer(to) <= layer(from),
            "matching/deep: {from} (layer {:?}) names {to} (layer {:?})",
            layer(from),
            layer(to)
        );
    }
    // No circle: repeatedly remove modules that name none left.
    let mut left: Vec<&str> = DEEP_LAYERS.iter().map(|(m, _)| *m).collect();
    while let Some(k) = left
        .iter()
        .position(|m| !edges.iter().any(|(f, t)| f == m && left.contains(t)))
    {
        left.remove(k);
    }
    assert!(
        left.is_empty(),
        "matching/deep: a circle among {left:?}: {edges:?}"
    );
}

/// Lines of code of `text`: not blank, not a comment.
fn code_lines(text: &str) -> usize {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("//"))
        .count()
}

/// No file under `src/` passes 600 lines of code (blank lines and
/// comments aside); a file's inline test module is counted apart, as a
/// test module's own file is, against the same limit.
#[test]
fn no_file_passes_600_code_lines() {
    const LIMIT: usize = 600;
    let mut files = Vec::new();
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
    walk(&src(), &mut files);
    let mut over = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        let (code, tests) = match text.find("#[cfg(test)]\nmod tests {") {
            Some(k) => text.split_at(k),
            None => (text.as_str(), ""),
        };
        for (part, n) in [("code", code_lines(code)), ("tests", code_lines(tests))] {
            if n > LIMIT {
                let rel = f.strip_prefix(src()).unwrap().display().to_string();
                over.push(format!("src/{rel} ({part}): {n}"));
            }
        }
    }
    assert!(over.is_empty(), "over {LIMIT} code lines: {over:?}");
}

#[test]
fn only_io_writes_files_and_only_batch_and_bridge_start_processes() {
    only_in(
        &[
            "std::fs::write",
            "File::create",
            "OpenOptions",
            "create_dir",
            "std::fs::rename",
            "remove_dir",
            "tempfile",
            "std::fs::copy",
        ],
        &["io/", "bridge/", "interrupt.rs"],
    );
    // The bridge writes only inside SUMO's Python environment (its
    // requirements and stamp) and removes its own capture of SUMO's stderr.
    let bridge = ["bridge/mod.rs", "bridge/python.rs"]
        .map(|f| std::fs::read_to_string(src().join(f)).unwrap())
        .join("\n");
    for line in bridge.lines().filter(|l| l.contains("std::fs::write")) {
        assert!(
            line.contains("std::fs::write(&req") || line.contains("venv.join(STAMP)"),
            "{line}"
        );
    }
    // Reading: the config file, weights, batch folders, the venv.
    only_in(
        &["std::fs::read", "File::open", "read_dir"],
        &[
            "config/mod.rs",
            "config/lists.rs",
            "config/appearance.rs",
            "config/digest.rs",
            "io/",
            "bridge/",
        ],
    );
    // No fixed or predictable paths under /tmp: temporary files and
    // folders come from tempfile (unpredictable names). The bridge lists
    // the temporary folder only to remove its own capture folders left by
    // processes that are gone.
    only_in(&["\"/tmp"], &[]);
    only_in(&["temp_dir()"], &["bridge/"]);
    // Batch starts its workers; the bridge runs SUMO's netconvert.
    only_in(
        &["std::process::Command", "process::{"],
        &["batch.rs", "bridge/"],
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
    // oracle, the evaluation, the tables, the detector report and the
    // pictures that score and draw it, cooperation over time (which scores
    // its association and fusion), and the pipeline and render command
    // that pass it along.
    only_in(
        &["ObservationTruth", "DetectionTruth", ".truth$"],
        &[
            "sensor/mod.rs",
            "sensor/camera.rs",
            "sensor/profile/sense.rs",
            "sensor/boxes.rs",
            "sensor/reid/",
            "matching/oracle.rs",
            "evaluate/mod.rs",
            "evaluate/counts.rs",
            "evaluate/sources.rs",
            "evaluate/pair.rs",
            "evaluate/frame.rs",
            "evaluate/map.rs",
            "evaluate/estimates.rs",
            "tables/record.rs",
            "report/detector.rs",
            "render/scene.rs",
            "pipeline/instance.rs",
            "pipeline/simulate.rs",
            "v2x/estimates.rs",
            "v2x/fleet.rs",
            "v2x/message.rs",
            "v2x/peer.rs",
            "v2x/receptions.rs",
            "v2x/vehicle.rs",
            "experiments/",
            "export/rows.rs",
            // A converted dataset's truth rows: the source's labels; a
            // dataset's truth read back beside its instances.
            "dataset/convert.rs",
            "pipeline/replay.rs",
            "cli/render.rs",
            // A dataset's truth rows from elsewhere, written as given.
            "dataset/write.rs",
            "commands/dataset.rs",
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

/// `lib.rs` makes public exactly the modules the binary, the tests, the
/// benches and the Python extension name (`coid_sim::x`); every other module is private to the
/// crate, so the compiler keeps outsiders out of it.
#[test]
fn the_library_exports_only_what_its_users_name() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut named = std::collections::BTreeSet::new();
    let mut files = vec![root.join("src/main.rs")];
    for dir in ["tests", "benches", "python/src"] {
        let mut stack = vec![root.join(dir)];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.extension().is_some_and(|x| x == "rs") {
                    files.push(p);
                }
            }
        }
    }
    for f in files.iter().filter(|f| !f.ends_with("architecture.rs")) {
        let text = std::fs::read_to_string(f).unwrap();
        for (k, _) in text.match_indices("coid_sim::") {
            let rest = &text[k + "coid_sim::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            named.insert(name);
        }
    }
    let lib = std::fs::read_to_string(src().join("lib.rs")).unwrap();
    let public: std::collections::BTreeSet<String> = lib
        .lines()
        .filter_map(|l| l.strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';').to_owned())
        .collect();
    assert_eq!(
        public, named,
        "lib.rs's `pub mod`s against what main, tests, benches and the Python extension name"
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

#[test]
fn the_dependency_reader_sees_groups_inline_paths_and_macros_but_not_tests() {
    let code = "use crate::{io, geometry::Vec2};\n\
                use std::fmt;\n\
                fn f() { crate::rng::stream(); let _ = format!(\"{}\", crate::label::X); }\n\
                crate::label_enum! { \"x\"; pub enum E { A } }\n\
                #[cfg(test)]\nmod tests { use crate::cli; }\n\
                #[cfg(test)]\nfn helper() { crate::batch::run(); }\n";
    assert_eq!(crate_deps("x.rs", code), ["geometry", "io", "label", "rng"]);
    // `super::` reaches the crate root from a top-level module, and stays
    // inside the module from deeper files.
    let code = "use super::{fusion, io::x};\nfn f() { super::rng::stream(); }\n";
    assert_eq!(crate_deps("cli.rs", code), ["fusion", "io", "rng"]);
    assert_eq!(crate_deps("cli/mod.rs", code), ["fusion", "io", "rng"]);
    assert!(crate_deps("cli/run.rs", code).is_empty());
    let deeper = "use super::super::geometry::Vec2;\n";
    assert_eq!(crate_deps("cli/run.rs", deeper), ["geometry"]);
}

/// Words of the project's process, not of the product: an issue's
/// number, a commit, the owner's decisions, and the phrases that
/// measure the product against a past state of it ("before this work",
/// "the earlier weights", "today's model").
fn process_words(text: &str) -> Vec<String> {
    // ASCII lowercase keeps every byte where it was.
    let lower = text.to_ascii_lowercase();
    let mut found = Vec::new();
    for sep in ["issue ", "issue-"] {
        for (k, _) in lower.match_indices(sep) {
            let start = k + sep.len();
            let digits = lower[start..]
                .bytes()
                .take_while(u8::is_ascii_digit)
                .count();
            if digits > 0 {
                found.push(text[k..start + digits].to_owned());
            }
        }
    }
    for word in [
        "(commit ",
        "owner's decision",
        "owner's call",
        "the owner's",
        "product's owner",
        "issue's",
        "the issue asks",
        "the issue aims",
        "this issue",
        "this work",
        "this update",
        "earlier weights",
        "earlier recipe",
        "the retraining",
        // `today's` alone also names a record's current field names
        // (deep::arch reads older ones too), which is the product.
        "today's model",
        "today's demand",
        "today's tables",
        "are today's",
        "keeps today's",
        "which today",
    ] {
        if lower.contains(word) {
            found.push(word.to_owned());
        }
    }
    found
}

/// README, ARCHITECTURE.md, every page of docs/ and the comments of
/// `src/` speak of the product as it is: no issue numbers, no
/// commits, no owner's decisions, no "before this work" (the history
/// is CHANGELOG.md's).
#[test]
fn the_docs_and_the_code_speak_of_the_product_not_its_history() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut texts: Vec<(String, String)> = ["README.md", "ARCHITECTURE.md"]
        .iter()
        .map(|f| {
            (
                f.to_string(),
                std::fs::read_to_string(root.join(f)).unwrap(),
            )
        })
        .collect();
    let mut pages: Vec<String> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".md"))
        .collect();
    pages.sort();
    for page in &pages {
        let text = std::fs::read_to_string(root.join("docs").join(page)).unwrap();
        texts.push((format!("docs/{page}"), text));
    }
    for (rel, code) in sources() {
        let comments: String = code
            .lines()
            .filter(|l| l.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        texts.push((format!("src/{rel}"), comments));
    }
    let bad: Vec<String> = texts
        .iter()
        .flat_map(|(f, t)| {
            process_words(t)
                .into_iter()
                .map(move |w| format!("{f}: {w}"))
        })
        .collect();
    assert!(bad.is_empty(), "process words: {bad:?}");
    assert_eq!(
        process_words("see issue 49 and Issue-33"),
        ["issue 49", "Issue-33"]
    );
    assert_eq!(
        process_words("Before this work, with today's model"),
        ["this work", "today's model"]
    );
}

/// The Python package calls the library's typed commands: it builds no
/// command line (argv goes to coid only from the user, through
/// `coid_sim.cli` and `python -m coid_sim`), parses no printed line and
/// writes no file of its own (a dict configuration goes as text, a frame
/// of matches as bytes), in its Python code and its extension alike.
#[test]
fn the_python_package_builds_no_command_line_and_parses_no_printed_line() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("python");
    let mut offences = Vec::new();
    for dir in ["src_py/coid_sim", "src"] {
        for e in std::fs::read_dir(root.join(dir)).unwrap() {
            let path = e.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if !(name.ends_with(".py") || name.ends_with(".rs")) {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let python = name.ends_with(".py");
            for (k, line) in text.lines().enumerate() {
                // Code without its comment; a docstring's example
                // (``cli("eval", ...)``) is no call.
                let code = if python {
                    line.split('#').next().unwrap_or("")
                } else {
                    line.split("//").next().unwrap_or("")
                };
                if python && code.contains("``") {
                    continue;
                }
                let at = format!("python/{dir}/{name}:{}: {}", k + 1, line.trim());
                // The two doors through which a user's own argv comes in.
                let door = (name == "__init__.py"
                    && code.contains("return _coid_sim.call([\"coid\", *"))
                    || (name == "__main__.py"
                        && code.contains("_coid_sim.main([\"coid\", *sys.argv[1:]])"));
                let option = code
                    .match_indices("\"--")
                    .any(|(i, _)| !code[..i].ends_with('\\'))
                    || code.contains("'--");
                let argv = option
                    || code.contains("_coid_sim.call(")
                    || code.contains("_coid_sim.main(")
                    || (python
                        && code.contains("cli(")
                        && !code.trim_start().starts_with("def cli("));
                if argv && !door {
                    offences.push(format!("builds a command line: {at}"));
                }
                if code.contains("; wrote")
                    || code.contains("rsplit(")
                    || code.contains(".split(\"; ")
                {
                    offences.push(format!("parses a printed line: {at}"));
                }
                if code.contains("tempfile")
                    || code.contains("write_text(")
                    || code.contains("NamedTemporary")
                {
                    offences.push(format!("writes a file of its own: {at}"));
                }
            }
        }
    }
    assert!(offences.is_empty(), "{offences:#?}");
}

/// The sections of `Settings`, as fields.
const SETTINGS_SECTIONS: [&str; 16] = [
    "source",
    "scenario",
    "connected",
    "link",
    "seeds",
    "camera",
    "sensor",
    "pose_noise",
    "matching",
    "fusion",
    "train",
    "eval",
    "v2x",
    "detector",
    "appearance",
    "dataset",
];

/// Whether `line` writes into a section of settings: assigns to
/// `x.<section>...`, calls a mutating method on it, or borrows it
/// mutably.
fn writes_a_section(line: &str) -> bool {
    const MUTATING: [&str; 12] = [
        ".push(",
        ".retain(",
        ".clear(",
        ".insert(",
        ".extend(",
        ".clone_from(",
        ".as_mut(",
        ".truncate(",
        ".get_mut(",
        ".iter_mut(",
        ".take(",
        ".sort",
    ];
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    SETTINGS_SECTIONS.iter().any(|section| {
        let needle = format!(".{section}");
        line.match_indices(&needle).any(|(k, _)| {
            let before = line[..k].chars().next_back();
            let mut rest = &line[k + needle.len()..];
            if !before.is_some_and(ident) || rest.starts_with(ident) {
                return false;
            }
            let receiver_start = line[..k].rfind(|c: char| !ident(c)).map_or(0, |i| i + 1);
            if line[..receiver_start].trim_end().ends_with("&mut") {
                return true;
            }
            // The rest of the field chain.
            while let Some(r) = rest.strip_prefix('.') {
                let n = r.find(|c: char| !ident(c)).unwrap_or(r.len());
                if n == 0 || r[n..].starts_with('(') {
                    break;
                }
                rest = &r[n..];
            }
            let t = rest.trim_start();
            let assigns = (t.starts_with('=') && !t.starts_with("==") && !t.starts_with("=>"))
                || ["+=", "-=", "*=", "/="].iter().any(|op| t.starts_with(op));
            assigns || MUTATING.iter().any(|m| rest.starts_with(m))
        })
    })
}

/// Settings do not change after validation: outside `config` (whose
/// constructors make a run's, a pass's or a sweep point's settings as new
/// values, `config/variants.rs`), no code writes into a section of
/// `Settings`; what validation finds travels beside them
/// (`pipeline::Found`). A detection's `appearance` is no setting.
#[test]
fn nothing_outside_config_writes_into_settings() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files: Vec<(String, String)> = sources()
        .into_iter()
        .filter(|(rel, _)| !rel.starts_with("config/"))
        .collect();
    for f in ["commands.rs", "lib.rs"] {
        let p = root.join("python/src").join(f);
        files.push((
            format!("python/src/{f}"),
            std::fs::read_to_string(p).unwrap(),
        ));
    }
    let mut offenders = Vec::new();
    for (rel, code) in &files {
        for (n, line) in code.lines().enumerate() {
            let l = line.trim_start();
            if l.starts_with("//") || l.contains("det.appearance") {
                continue;
            }
            if writes_a_section(line) {
                offenders.push(format!("{rel}:{}: {}", n + 1, l));
            }
        }
    }
    assert!(offenders.is_empty(), "{offenders:#?}");
    // The check finds what it looks for.
    for written in [
        "s.matching.models_dir = dir;",
        "settings.eval.traffic_seeds.truncate(2);",
        "(v.apply)(&mut s.v2x);",
        "let Some(reid) = settings.appearance.reid.as_mut() else {",
        "run.scenario.sample_every_s += 1.0;",
    ] {
        assert!(writes_a_section(written), "{written}");
    }
    for read in [
        "let dir = s.matching.models_dir.clone();",
        "if s.matching.lambda == LambdaChoice::Validated {",
        "(Some(d), Some(_)) if self.appearance => {",
        "let n = s.train.runs_per_scenario.min(s.eval.traffic_seeds.len());",
    ] {
        assert!(!writes_a_section(read), "{read}");
    }
}
