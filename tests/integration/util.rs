//! What every test module uses: the binary, a temporary folder to run it
//! in, readers of its tables.

use std::ffi::{OsStr, OsString};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

use polars::prelude::*;

pub const BIN: &str = env!("CARGO_BIN_EXE_coid");

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// SUMO's Python environment: `COID_VENV`, or the checkout's `.venv`
/// (never a new download).
pub fn venv() -> PathBuf {
    std::env::var_os("COID_VENV").map_or_else(|| repo().join(".venv"), PathBuf::from)
}

/// The `coid` binary in `dir`, with its data folder there too (each test
/// writes out the carried files for itself) and SUMO's environment
/// (`venv`).
pub fn coid_in(dir: &Path) -> Command {
    let mut c = Command::new(BIN);
    c.current_dir(dir)
        .env("COID_HOME", dir.join(".coid-home"))
        .env("COID_VENV", venv());
    c
}

/// Sends `signal` (`-INT`, `-KILL`, ...) to `child` with kill(1).
pub fn send_signal(child: &Child, signal: &str) {
    let pid = child.id().to_string();
    let sent = Command::new("kill").args([signal, &pid]).status();
    assert!(sent.unwrap().success(), "kill {signal} {pid}");
}

pub fn shipped_sumocfg() -> PathBuf {
    repo().join("sumo_nets/intersection/intersection.sumocfg")
}

/// A config's `[scenario]` section: `sumocfg` and `junction`, nothing else.
pub fn scenario_toml(sumocfg: &Path, junction: &str) -> String {
    format!(
        "[scenario]\nsumocfg = {:?}\njunction = \"{junction}\"\n",
        sumocfg.to_string_lossy()
    )
}

/// A temporary folder with helpers to write configs and run the binary.
pub struct Fixture {
    pub dir: tempfile::TempDir,
}

impl Fixture {
    pub fn new() -> Self {
        Fixture {
            dir: tempfile::tempdir().expect("temp dir"),
        }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Writes a config: the shipped scenario, run for `end_s`, plus `extra`
    /// TOML (sections after `[scenario]`). Everything else comes from the
    /// defaults, the shipped weights included.
    pub fn config(&self, name: &str, end_s: f64, extra: &str) -> PathBuf {
        let scenario = scenario_toml(&shipped_sumocfg(), "C");
        self.write(name, &format!("{scenario}end_s = {end_s}\n{extra}"))
    }

    /// A 60 s config running `method` alone with the weights of the
    /// fixture's folder `models` (which need not exist).
    pub fn method_config(&self, name: &str, method: &str, models: &str) -> PathBuf {
        let extra = format!(
            "[matching]\nmethods = [{method:?}]\nmodels_dir = {:?}\n",
            self.path(models).to_string_lossy()
        );
        self.config(name, 60.0, &extra)
    }

    /// A new fixture holding one config, `c.toml`, as `config` writes it.
    pub fn with_config(end_s: f64, extra: &str) -> (Fixture, PathBuf) {
        let fx = Fixture::new();
        let config = fx.config("c.toml", end_s, extra);
        (fx, config)
    }

    pub fn write(&self, name: &str, body: &str) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, body).expect("write");
        p
    }

    /// The contents of the file `name`.
    pub fn read(&self, name: &str) -> Vec<u8> {
        std::fs::read(self.path(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    /// The text of the file `name`.
    pub fn read_text(&self, name: &str) -> String {
        std::fs::read_to_string(self.path(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    pub fn coid(&self, args: &[&str]) -> Output {
        self.cmd(args[0]).args(&args[1..]).output()
    }

    /// `coid <command>` in this folder, its arguments to be added.
    pub fn cmd(&self, command: &str) -> Cmd<'_> {
        Cmd {
            dir: self.dir.path(),
            args: vec![command.into()],
            env: Vec::new(),
        }
    }

    /// `coid run --quiet --config <config> --out <out>`.
    pub fn run(&self, config: &Path, out: &str) -> Output {
        self.cmd("run").quiet().config(config).out(out).output()
    }
}

/// A `coid` command line being built (`Fixture::cmd`).
pub struct Cmd<'a> {
    dir: &'a Path,
    args: Vec<OsString>,
    env: Vec<(OsString, OsString)>,
}

impl Cmd<'_> {
    pub fn arg(mut self, arg: impl AsRef<OsStr>) -> Self {
        self.args.push(arg.as_ref().to_owned());
        self
    }

    pub fn args<S: AsRef<OsStr>>(mut self, args: impl IntoIterator<Item = S>) -> Self {
        self.args
            .extend(args.into_iter().map(|a| a.as_ref().to_owned()));
        self
    }

    /// `--quiet`.
    pub fn quiet(self) -> Self {
        self.arg("--quiet")
    }

    /// `--config <config>`.
    pub fn config(self, config: &Path) -> Self {
        self.arg("--config").arg(config)
    }

    /// `--out <out>`.
    pub fn out(self, out: &str) -> Self {
        self.arg("--out").arg(out)
    }

    /// The environment variable `key` set to `value`.
    pub fn env(mut self, key: &str, value: impl AsRef<OsStr>) -> Self {
        self.env.push((key.into(), value.as_ref().to_owned()));
        self
    }

    /// The command, to set more on (pipes).
    pub fn command(self) -> Command {
        let mut c = coid_in(self.dir);
        c.args(&self.args).envs(self.env);
        c
    }

    /// Runs it to the end.
    pub fn output(self) -> Output {
        self.command().output().expect("run coid")
    }

    /// Starts it without waiting, its stderr piped.
    pub fn spawn(self) -> Child {
        self.command()
            .stderr(Stdio::piped())
            .spawn()
            .expect("start coid")
    }
}

/// When the file at `p` was last modified.
pub fn modified(p: &Path) -> std::time::SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn assert_ok(o: &Output) {
    assert!(o.status.success(), "coid failed: {}", stderr(o));
}

/// Polls `done` every 10 ms until it holds; fails with `what` once
/// `deadline` has passed.
pub fn wait_until(deadline: std::time::Instant, what: &str, mut done: impl FnMut() -> bool) {
    while !done() {
        assert!(std::time::Instant::now() < deadline, "{what}");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

pub fn read_csv(path: &Path) -> DataFrame {
    CsvReadOptions::default()
        .with_has_header(true)
        .try_into_reader_with_file_path(Some(path.to_owned()))
        .expect("csv reader")
        .finish()
        .expect("read csv")
}

pub fn read_parquet(path: &Path) -> DataFrame {
    ParquetReader::new(File::open(path).expect("open parquet"))
        .finish()
        .expect("read parquet")
}

pub fn f64s(df: &DataFrame, col: &str) -> Vec<f64> {
    df.column(col)
        .unwrap()
        .cast(&DataType::Float64)
        .unwrap()
        .f64()
        .unwrap()
        .iter()
        .map(|v| v.unwrap_or(f64::NAN))
        .collect()
}

pub fn strs(df: &DataFrame, col: &str) -> Vec<String> {
    df.column(col)
        .unwrap()
        .str()
        .unwrap()
        .iter()
        .map(|v| v.unwrap_or("").to_owned())
        .collect()
}

/// A command refused as coid refuses: exit code 1, no panic, and one line
/// on stderr, `error: ...`, that holds `expect`.
pub fn assert_refused(o: &Output, expect: &str) {
    let err = stderr(o);
    assert_eq!(
        o.status.code(),
        Some(1),
        "expected a refusal ({expect}): {err}"
    );
    assert!(!err.contains("panicked"), "panic: {err}");
    assert_eq!(err.trim().lines().count(), 1, "not one line: {err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains(expect), "expected {expect:?} in: {err}");
}

/// `assert_refused`, and nothing written at `unwritten`.
pub fn assert_refused_unwritten(o: &Output, expect: &str, unwritten: &Path) {
    assert_refused(o, expect);
    assert!(!unwritten.exists(), "{} was written", unwritten.display());
}

/// Asserts that the CSV text `got` is byte for byte `expected` (`what`
/// names it). On a difference, names it: the header's columns if they
/// differ, the row counts, and the first few differing cells by row and
/// column with both values. Plain CSV: no quoted commas.
pub fn assert_same_csv(got: &str, expected: &str, what: &str) {
    if got != expected {
        panic!("{what} differs:\n{}", csv_differences(got, expected));
    }
}

/// What `assert_same_csv` says about two texts that differ.
pub fn csv_differences(got: &str, expected: &str) -> String {
    const SHOWN: usize = 8;
    let table = |text: &str| -> Vec<Vec<String>> {
        text.lines()
            .map(|l| l.split(',').map(str::to_owned).collect())
            .collect()
    };
    let (got, expected) = (table(got), table(expected));
    let empty = Vec::new();
    let (got_header, expected_header) = (
        got.first().unwrap_or(&empty),
        expected.first().unwrap_or(&empty),
    );
    let mut out = Vec::new();
    if got_header != expected_header {
        let missing: Vec<&String> = expected_header
            .iter()
            .filter(|c| !got_header.contains(c))
            .collect();
        let extra: Vec<&String> = got_header
            .iter()
            .filter(|c| !expected_header.contains(c))
            .collect();
        out.push(format!(
            "header: columns missing {missing:?}, extra {extra:?}\n  got      {got_header:?}\n  expected {expected_header:?}"
        ));
    }
    if got.len() != expected.len() {
        out.push(format!(
            "{} data rows, expected {}",
            got.len().saturating_sub(1),
            expected.len().saturating_sub(1)
        ));
    }
    // Cells compared by column name, rows by position (row 1: the first
    // after the header); a row is labelled by its first three cells.
    let mut cells = Vec::new();
    for (k, (g, e)) in got.iter().zip(&expected).enumerate().skip(1) {
        let label = e.iter().take(3).cloned().collect::<Vec<_>>().join("/");
        for (j, name) in expected_header.iter().enumerate() {
            let Some(i) = got_header.iter().position(|c| c == name) else {
                continue;
            };
            let (gv, ev) = (g.get(i), e.get(j));
            if gv != ev {
                cells.push(format!(
                    "row {k} ({label}), column {name}: got {}, expected {}",
                    gv.map_or("(none)", String::as_str),
                    ev.map_or("(none)", String::as_str)
                ));
            }
        }
    }
    if !cells.is_empty() {
        let more = cells.len().saturating_sub(SHOWN);
        cells.truncate(SHOWN);
        out.extend(cells);
        if more > 0 {
            out.push(format!("... and {more} more differing cell(s)"));
        }
    }
    if out.is_empty() {
        out.push("the same cells, other bytes (line endings or a last newline)".into());
    }
    out.join("\n")
}

/// The names in `dir`, sorted (nothing when it does not exist).
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}
