//! The `coid` command line: parses arguments, loads the config, runs the
//! pipeline with a progress bar and writes the results. Errors are printed
//! as one line (the cause chain joined by ": ") with exit code 1.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use coid_sim::config::{FusionVariant, PoseNoiseLabel, Settings};
use coid_sim::matching::Method;
use coid_sim::{experiments, output, pipeline};

#[derive(Parser)]
#[command(
    name = "coid",
    version,
    about = "Correspondence identification and fusion for connected vehicles at a SUMO intersection",
    long_about = "coid-sim runs a SUMO intersection headless, derives each connected vehicle's camera \
detections (occlusion, noise, misses, false positives, GPS pose error), matches the detections of \
every pair of connected vehicles, fuses the matched measurements and reports precision, recall, F1 \
and displacement error, single-vehicle vs fused, per method, pose-noise level and fusion variant."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run one scenario headless and write summary.csv, objects.parquet and summary.md.
    Run {
        /// Configuration file (TOML); relative paths inside it resolve against its folder.
        #[arg(long, short, default_value = "configs/default.toml")]
        config: PathBuf,
        /// Output folder [default: results/<config file stem>].
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Replace the output folder if it exists (the old one is removed only
        /// after the new one is complete).
        #[arg(long)]
        force: bool,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
        /// Override [seeds] traffic (SUMO's seed).
        #[arg(long)]
        traffic_seed: Option<u64>,
        /// Override [seeds] sensor.
        #[arg(long)]
        sensor_seed: Option<u64>,
    },
    /// Run a Monte Carlo batch: N runs with seeds derived from one master
    /// seed, on W worker processes, resumable (run the same command again to
    /// finish a killed batch), aggregated into <out>/summary.csv with 95%
    /// confidence intervals. Each run keeps its own folder in <out>/runs/.
    Batch {
        /// Configuration file (TOML).
        #[arg(long, short, default_value = "configs/default.toml")]
        config: PathBuf,
        /// Number of runs.
        #[arg(long)]
        runs: usize,
        /// Worker processes [default: the number of cores].
        #[arg(long, short)]
        workers: Option<usize>,
        /// Master seed: run i gets traffic and sensor seeds derived from it.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder [default: results/<config file stem>-batch].
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Only this slice of the runs, `k/n` (1-based): runs i with
        /// i mod n = k - 1; combine the shards' folders with `coid merge`.
        #[arg(long)]
        shard: Option<coid_sim::batch::Shard>,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Combine batch shard folders into one aggregate, identical to the
    /// unsharded batch's.
    Merge {
        /// Shard folders (each made by `coid batch --shard k/n`).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Output folder.
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Draw chosen instances top-down (PNG and SVG): roads, buildings, road
    /// users, camera frustums, detections and the correspondences of one
    /// method (green right, red wrong, thicker = more uncertain).
    Render {
        /// Configuration file (TOML).
        #[arg(long, short, default_value = "configs/default.toml")]
        config: PathBuf,
        /// Output folder [default: results/<config file stem>-render].
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Instance indices to draw (0 = the run's first instance).
        #[arg(long, value_delimiter = ',', default_value = "0")]
        instances: Vec<usize>,
        /// Method whose correspondences are drawn.
        #[arg(long, default_value = "ours")]
        method: String,
        /// Pose-noise level of the drawn correspondences: none, rtk or gps.
        #[arg(long, default_value = "gps")]
        pose_noise: String,
        /// Replace the output folder if it exists.
        #[arg(long)]
        force: bool,
    },
    /// Evaluate every method on the test runs ([eval] traffic_seeds) and write
    /// the paper's tables: table1.csv (P/R/F1 per method and pose noise),
    /// table2.csv (F1 before/after uncertainty thresholding), table3.csv
    /// (uncertainty types), lambda_sweep.csv, case_study.csv; means with 95%
    /// confidence intervals over runs.
    Eval {
        /// Configuration file (TOML).
        #[arg(long, short, default_value = "configs/default.toml")]
        config: PathBuf,
        /// Output folder [default: results/<config file stem>-eval].
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Replace the output folder if it exists.
        #[arg(long)]
        force: bool,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Train the deep matchers on instances from the training runs
    /// ([train] traffic_seeds) and save their weights, config and loss curve.
    Train {
        /// Configuration file (TOML).
        #[arg(long, short, default_value = "configs/default.toml")]
        config: PathBuf,
        /// Models folder [default: [matching] models_dir of the config].
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Train only these methods (labels as in the config) [default: [train] methods].
        #[arg(long, value_delimiter = ',')]
        methods: Vec<String>,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
}

fn default_out(config: &Path) -> PathBuf {
    let stem = config
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into());
    PathBuf::from("results").join(stem)
}

fn run(
    config: &Path,
    out: Option<PathBuf>,
    force: bool,
    quiet: bool,
    seeds: (Option<u64>, Option<u64>),
) -> anyhow::Result<()> {
    let mut settings = Settings::load(config)?;
    if let Some(t) = seeds.0 {
        settings.seeds.traffic = t;
    }
    if let Some(s) = seeds.1 {
        settings.seeds.sensor = s;
    }
    let out = out.unwrap_or_else(|| default_out(config));
    if out.exists() && !force {
        return Err(output::OutputError::Exists(out).into());
    }
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        let bar = ProgressBar::new((settings.scenario.end_s * 10.0).round() as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} SUMO t = {msg} [{bar:30}] {percent:>3}% elapsed {elapsed} eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar
    };
    let results = pipeline::run(&settings, |p| {
        bar.set_position((p.time_s * 10.0).round() as u64);
        bar.set_message(format!("{:6.1} s, {} instances", p.time_s, p.instances));
    })
    .context("run failed")?;
    bar.finish_and_clear();
    output::write_run(&out, &settings, &results, force)?;

    let rows = results.summary.rows();
    let pick = |m: Method| {
        rows.iter().find(|r| {
            r.key.method == m
                && r.key.pose_noise == PoseNoiseLabel::Gps
                && r.key.fusion == FusionVariant::Aligned
        })
    };
    let mut line = format!(
        "coid: {} instances in {:.1} s of traffic ({:.1} s wall, SUMO bridge {:.2} ms/step)",
        results.n_instances,
        results.sim_end_s,
        results.wall_time.as_secs_f64(),
        results.bridge_time.as_secs_f64() * 1e3 / results.n_steps.max(1) as f64,
    );
    for m in [Method::Ours, Method::GpsHungarian, Method::Oracle] {
        if let Some(r) = pick(m) {
            line.push_str(&format!(
                "; {} @gps/aligned F1 {:.3}, DE {:.2} -> {:.2} m",
                m.as_str(),
                r.f1,
                r.de_single_m,
                r.de_fused_m
            ));
        }
    }
    line.push_str(&format!("; wrote {}", out.display()));
    eprintln!("{line}");
    Ok(())
}

fn bar(quiet: bool, len: u64, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

fn train(
    config: &Path,
    out: Option<PathBuf>,
    methods: &[String],
    quiet: bool,
) -> anyhow::Result<()> {
    let settings = Settings::load(config)?;
    let models_dir = out.unwrap_or_else(|| settings.matching.models_dir.clone());
    let methods: Vec<Method> = if methods.is_empty() {
        settings.train.methods.clone()
    } else {
        methods
            .iter()
            .map(|m| {
                toml::Value::String(m.clone())
                    .try_into::<Method>()
                    .map_err(|_| anyhow::anyhow!("unknown method '{m}'"))
            })
            .collect::<anyhow::Result<_>>()?
    };
    if let Some(m) = methods
        .iter()
        .find(|m| coid_sim::matching::deep::variant(**m).is_none())
    {
        anyhow::bail!("'{}' is not a trainable (deep) method", m.as_str());
    }
    let runs = settings.train.traffic_seeds.len() as u64;
    let pb = bar(
        quiet,
        runs,
        "{spinner} collecting training pairs: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let examples = experiments::collect_examples(&settings, |_, _, n| {
        pb.inc(1);
        pb.set_message(format!("{n} pairs"));
    })
    .context("collecting training data failed")?;
    pb.finish_and_clear();
    eprintln!("coid: {} training pairs from {} runs", examples.len(), runs);
    for method in methods {
        let started = std::time::Instant::now();
        let total = (settings.train.epochs * examples.len()) as u64;
        let pb = bar(
            quiet,
            total,
            &format!(
                "{{spinner}} training {:<9} [{{bar:30}}] {{pos}}/{{len}} steps, {{msg}} eta {{eta}}",
                method.as_str()
            ),
        );
        let mut smooth = f32::NAN;
        let (net, report) =
            experiments::train_method(&settings, method, &examples, |step, _, loss| {
                smooth = if smooth.is_nan() {
                    loss
                } else {
                    0.98 * smooth + 0.02 * loss
                };
                pb.set_position(step as u64);
                if step % 20 == 0 {
                    pb.set_message(format!("loss {smooth:.3}"));
                }
            })
            .map_err(|e| anyhow::anyhow!("training {} failed: {e}", method.as_str()))?;
        pb.finish_and_clear();
        let record = output::TrainingRecord {
            method: method.as_str(),
            settings: &settings,
            n_examples: examples.len(),
            report: &report,
            seconds: started.elapsed().as_secs_f64(),
        };
        output::write_model(&models_dir, &record, |p| {
            coid_sim::matching::deep::model::save(&net, p)
        })?;
        eprintln!(
            "coid: trained {} in {:.0} s ({} steps), loss per epoch {:?}; wrote {}",
            method.as_str(),
            record.seconds,
            report.steps,
            report
                .epoch_losses
                .iter()
                .map(|l| (l * 1000.0).round() / 1000.0)
                .collect::<Vec<_>>(),
            coid_sim::matching::deep::weights_path(&models_dir, method).display()
        );
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn batch(
    config: &Path,
    runs: usize,
    workers: Option<usize>,
    seed: u64,
    out: Option<PathBuf>,
    shard: Option<coid_sim::batch::Shard>,
    quiet: bool,
) -> anyhow::Result<()> {
    use coid_sim::batch;
    // Validate the config once here, so a bad config fails before any run.
    Settings::load(config)?;
    if runs == 0 {
        anyhow::bail!("--runs must be at least 1");
    }
    let config = config
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", config.display()))?;
    let out = out.unwrap_or_else(|| {
        let stem = config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "run".into());
        PathBuf::from("results").join(format!("{stem}-batch"))
    });
    let workers = workers
        .unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        })
        .max(1);
    // A batch folder belongs to one (config, runs, seed): refuse to mix.
    let identity = format!(
        "config = {:?}\nruns = {runs}\nmaster_seed = {seed}\n",
        config.display().to_string()
    );
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let id_path = out.join("batch.toml");
    match std::fs::read_to_string(&id_path) {
        Ok(existing) if existing != identity => anyhow::bail!(
            "{} holds a different batch ({}); choose another --out",
            out.display(),
            existing.replace('\n', ", ").trim_end_matches(", ")
        ),
        Ok(_) => {}
        Err(_) => {
            let tmp = out.join(format!(".batch.toml.tmp-{}", std::process::id()));
            std::fs::write(&tmp, &identity)
                .and_then(|()| std::fs::rename(&tmp, &id_path))
                .with_context(|| format!("cannot write {}", id_path.display()))?;
        }
    }
    let pending = batch::pending_runs(&out, runs, shard);
    let mine = (0..runs)
        .filter(|i| shard.is_none_or(|s| i % s.count == s.index - 1))
        .count();
    let pb = bar(
        quiet,
        mine as u64,
        "{spinner} runs {pos}/{len} [{bar:30}] {per_sec} eta {eta} {msg}",
    );
    pb.set_position((mine - pending.len()) as u64);
    let exe = std::env::current_exe().context("cannot find the coid executable")?;
    let started = std::time::Instant::now();
    let mut failed_count = 0;
    let failures = batch::execute(&exe, &config, &out, seed, &pending, workers, |_, ok| {
        pb.inc(1);
        if !ok {
            failed_count += 1;
            pb.set_message(format!("{failed_count} failed"));
        }
    })
    .context("cannot start worker processes")?;
    pb.finish_and_clear();
    let completed = batch::completed_runs(&out)?;
    let rows = batch::aggregate(&completed)?;
    let header = format!(
        "- config: `{}`; master seed {seed}; {} of {runs} runs complete{}\n- means over runs, `±` the half-width of the 95% confidence interval (Student t)",
        config.display(),
        completed.len(),
        shard
            .map(|s| format!(" (this folder: shard {}/{})", s.index, s.count))
            .unwrap_or_default()
    );
    output::write_batch_summary(&out, &rows, &header)?;
    batch_plot(&out, &rows)?;
    eprintln!(
        "coid: {} runs done in {:.1} s on {workers} workers ({} complete in {}); aggregate in {}",
        pending.len() - failures.len(),
        started.elapsed().as_secs_f64(),
        completed.len(),
        out.display(),
        out.join("summary.csv").display()
    );
    if !failures.is_empty() {
        for f in &failures {
            eprintln!("coid: run {} failed: {}", f.run, f.message);
        }
        let list: Vec<String> = failures.iter().map(|f| f.run.to_string()).collect();
        anyhow::bail!(
            "{} run(s) failed: {} (the aggregate covers the {} complete runs; run the same command again to retry)",
            failures.len(),
            list.join(", "),
            completed.len()
        );
    }
    Ok(())
}

fn merge(dirs: &[PathBuf], out: &Path) -> anyhow::Result<()> {
    use coid_sim::batch;
    let mut identity: Option<String> = None;
    for d in dirs {
        let id = std::fs::read_to_string(d.join("batch.toml"))
            .with_context(|| format!("{} is not a batch folder (no batch.toml)", d.display()))?;
        match &identity {
            Some(i) if *i != id => anyhow::bail!(
                "{} belongs to a different batch than {}",
                d.display(),
                dirs[0].display()
            ),
            _ => identity = Some(id),
        }
    }
    std::fs::create_dir_all(out.join("runs"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    let mut total = 0;
    for d in dirs {
        for run in batch::completed_runs(d)? {
            let dst = out.join("runs").join(run.file_name().unwrap_or_default());
            output::copy_run(&run, &dst)?;
            total += 1;
        }
    }
    if let Some(id) = identity {
        std::fs::write(out.join("batch.toml"), id)
            .with_context(|| format!("cannot write into {}", out.display()))?;
    }
    let completed = batch::completed_runs(out)?;
    let rows = batch::aggregate(&completed)?;
    let header = format!(
        "- merged from {} shard folders; {} runs\n- means over runs, `±` the half-width of the 95% confidence interval (Student t)",
        dirs.len(),
        completed.len()
    );
    output::write_batch_summary(out, &rows, &header)?;
    eprintln!("coid: merged {total} runs into {}", out.display());
    Ok(())
}

fn render(
    config: &Path,
    out: Option<PathBuf>,
    instances: &[usize],
    method: &str,
    pose_noise: &str,
    force: bool,
) -> anyhow::Result<()> {
    let settings = Settings::load(config)?;
    let method: Method = toml::Value::String(method.to_owned())
        .try_into()
        .map_err(|_| anyhow::anyhow!("unknown method '{method}'"))?;
    let level = *settings
        .pose_noise
        .iter()
        .find(|l| l.label.as_str() == pose_noise)
        .ok_or_else(|| {
            anyhow::anyhow!("pose noise '{pose_noise}' is not one of the config's levels")
        })?;
    let out = out.unwrap_or_else(|| {
        let stem = config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "run".into());
        PathBuf::from("results").join(format!("{stem}-render"))
    });
    if out.exists() && !force {
        return Err(output::OutputError::Exists(out).into());
    }
    let matcher =
        coid_sim::matching::matcher_for(method, &settings.matching, settings.seeds.sensor)?;
    let tmp = out.with_file_name(format!(
        ".{}.tmp-{}",
        out.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        std::process::id()
    ));
    std::fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let mut drawn = Vec::new();
    let result = pipeline::simulate(
        &settings,
        |_| {},
        |inst| {
            if !instances.contains(&inst.index) {
                return Ok(());
            }
            let (va, vb) = inst.views(settings.seeds.sensor, &level);
            let matches = matcher.match_pair(&va, &vb);
            let c = coid_sim::eval::count_pairs(&inst.a.obs, &inst.b.obs, &matches);
            let view = coid_sim::render::SceneView {
                scene: inst.scene,
                frame: inst.frame,
                camera: &settings.camera,
                egos: [&inst.a.obs, &inst.b.obs],
                matches: &matches,
                caption: format!(
                    "{} @ {} pose noise, t = {:.1} s: {} vs {}, precision {:.2}, recall {:.2}",
                    method.as_str(),
                    level.label.as_str(),
                    inst.frame.time_s,
                    inst.a.obs.ego_id,
                    inst.b.obs.ego_id,
                    c.precision(),
                    c.recall()
                ),
                half_window_m: settings.camera.range_m + 10.0,
            };
            let stem = tmp.join(format!("instance-{:04}", inst.index));
            coid_sim::render::render_scene(&view, &stem, 1000)
                .map_err(|e| pipeline::RunError::Render(e.to_string()))?;
            drawn.push(inst.index);
            Ok(())
        },
    );
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e.into());
    }
    let missing: Vec<usize> = instances
        .iter()
        .copied()
        .filter(|i| !drawn.contains(i))
        .collect();
    if !missing.is_empty() {
        let _ = std::fs::remove_dir_all(&tmp);
        anyhow::bail!("the run has no instance(s) {missing:?} (it has fewer instances)");
    }
    if out.exists() {
        std::fs::remove_dir_all(&out)
            .with_context(|| format!("cannot replace {}", out.display()))?;
    }
    std::fs::rename(&tmp, &out).with_context(|| format!("cannot write {}", out.display()))?;
    eprintln!(
        "coid: drew {} instance(s) into {}",
        drawn.len(),
        out.display()
    );
    Ok(())
}

/// A batch's F1 per method (first fusion variant; F1 does not depend on
/// it) with 95% CIs, per pose-noise level; drawn under a temporary name,
/// then renamed.
fn batch_plot(out: &Path, rows: &[coid_sim::batch::AggregateRow]) -> anyhow::Result<()> {
    let Some(first_fusion) = rows.first().map(|r| r.fusion.clone()) else {
        return Ok(());
    };
    let rows: Vec<_> = rows.iter().filter(|r| r.fusion == first_fusion).collect();
    let mut methods: Vec<String> = rows.iter().map(|r| r.method.clone()).collect();
    methods.dedup();
    let mut levels: Vec<String> = rows.iter().map(|r| r.pose_noise.clone()).collect();
    levels.sort();
    levels.dedup();
    let series: Vec<(String, Vec<(f64, f64)>)> = levels
        .iter()
        .map(|l| {
            let v = methods
                .iter()
                .map(|m| {
                    rows.iter()
                        .find(|r| &r.method == m && &r.pose_noise == l)
                        .map(|r| r.f1)
                        .unwrap_or((f64::NAN, f64::NAN))
                })
                .collect();
            (l.clone(), v)
        })
        .collect();
    let tmp = out.join(format!(".f1_per_method.tmp-{}", std::process::id()));
    coid_sim::render::bars_with_ci(
        &tmp,
        "F1 per method (mean and 95% CI over runs)",
        "F1",
        &methods,
        &series,
    )?;
    for ext in ["png", "svg"] {
        std::fs::rename(
            tmp.with_extension(ext),
            out.join(format!("f1_per_method.{ext}")),
        )
        .with_context(|| format!("cannot write the plot into {}", out.display()))?;
    }
    Ok(())
}

/// `coid eval`'s plots: lambda sweep, error CDFs, F1 per method.
fn eval_plots(dir: &Path, d: &experiments::PlotData) -> Result<(), String> {
    use coid_sim::render::{Panel, bars_with_ci, cdf, line_panels};
    let sweep: Vec<Panel> = d
        .lambda_sweep
        .iter()
        .map(|(level, pts)| Panel {
            title: format!("ours, lambda sweep, pose noise {level}"),
            x_label: "lambda (entropy threshold, bits)".into(),
            y_label: "mean over test runs".into(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.05),
            series: vec![
                ("precision".into(), pts.iter().map(|p| (p.0, p.1)).collect()),
                ("recall".into(), pts.iter().map(|p| (p.0, p.2)).collect()),
                ("F1".into(), pts.iter().map(|p| (p.0, p.3)).collect()),
            ],
        })
        .collect();
    line_panels(&dir.join("lambda_sweep"), &sweep).map_err(|e| e.to_string())?;
    let max_err = d
        .errors
        .iter()
        .flat_map(|(_, s, f)| s.iter().chain(f))
        .cloned()
        .filter(|x| x.is_finite())
        .fold(1.0, f64::max)
        .min(10.0);
    let cdfs: Vec<Panel> = d
        .errors
        .iter()
        .map(|(level, s, f)| Panel {
            title: format!("ours, displacement error, pose noise {level}"),
            x_label: "error (m)".into(),
            y_label: "share of objects".into(),
            x_range: (0.0, max_err),
            y_range: (0.0, 1.0),
            series: vec![("single vehicle".into(), cdf(s)), ("fused".into(), cdf(f))],
        })
        .collect();
    line_panels(&dir.join("error_cdf"), &cdfs).map_err(|e| e.to_string())?;
    bars_with_ci(
        &dir.join("f1_per_method"),
        "F1 per method (mean and 95% CI over test runs)",
        "F1",
        &d.methods,
        &d.f1,
    )
    .map_err(|e| e.to_string())
}

/// Every method of the paper's Table 1 plus the practical ones.
const ALL_METHODS: [Method; 9] = [
    Method::Ours,
    Method::CoidNon,
    Method::CoidUnc,
    Method::Dgmc,
    Method::GcnGm,
    Method::Mogm,
    Method::Rgm,
    Method::GpsHungarian,
    Method::Oracle,
];

fn eval(config: &Path, out: Option<PathBuf>, force: bool, quiet: bool) -> anyhow::Result<()> {
    let settings = Settings::load(config)?;
    let out = out.unwrap_or_else(|| {
        let stem = config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "run".into());
        PathBuf::from("results").join(format!("{stem}-eval"))
    });
    if out.exists() && !force {
        return Err(output::OutputError::Exists(out).into());
    }
    let seeds = settings.eval.traffic_seeds.clone();
    let pb = bar(
        quiet,
        seeds.len() as u64,
        "{spinner} evaluating: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let mut runs = Vec::new();
    for &seed in &seeds {
        let run = experiments::settings_for_seed(&settings, seed);
        pb.set_message(format!("seed {seed}"));
        let r = experiments::eval_run(&run, &ALL_METHODS, |_| {})
            .with_context(|| format!("test run with seed {seed} failed"))?;
        runs.push(r);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let tables = experiments::eval_tables(&settings, &runs);
    let plots = experiments::plot_data(&settings, &runs);
    output::write_eval(&out, &settings, &tables, force, |dir| {
        eval_plots(dir, &plots)
    })?;
    let instances: usize = runs.iter().map(|r| r.instances).sum();
    eprintln!(
        "coid: evaluated {} methods on {} test runs ({instances} instances); wrote {}",
        ALL_METHODS.len(),
        runs.len(),
        out.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run {
            config,
            out,
            force,
            quiet,
            traffic_seed,
            sensor_seed,
        } => run(&config, out, force, quiet, (traffic_seed, sensor_seed)),
        Command::Batch {
            config,
            runs,
            workers,
            seed,
            out,
            shard,
            quiet,
        } => batch(&config, runs, workers, seed, out, shard, quiet),
        Command::Merge { dirs, out } => merge(&dirs, &out),
        Command::Render {
            config,
            out,
            instances,
            method,
            pose_noise,
            force,
        } => render(&config, out, &instances, &method, &pose_noise, force),
        Command::Train {
            config,
            out,
            methods,
            quiet,
        } => train(&config, out, &methods, quiet),
        Command::Eval {
            config,
            out,
            force,
            quiet,
        } => eval(&config, out, force, quiet),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", chain.join(": "));
            ExitCode::FAILURE
        }
    }
}
