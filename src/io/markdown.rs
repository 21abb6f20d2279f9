//! The human-readable reports (`summary.md`) of a run, an evaluation and a
//! batch: plain text built from the report types.

use std::fmt::Write as _;

use std::collections::BTreeMap;

use crate::config::Settings;
use crate::matching::deep::decision::UncertaintyKind;
use crate::matching::{DeepChoice, LambdaChoice, Method};
use crate::report::{AggregateRow, Metric, RunResults, SummaryRow, Table, TableColumn};

/// A number with `digits` decimals, "n/a" when it is not finite.
pub fn fmt_num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "n/a".into()
    }
}

/// `mean ± ci`, or the mean alone when the interval is not finite.
fn with_ci(m: f64, ci: f64) -> String {
    if ci.is_finite() {
        format!("{} ± {}", fmt_num(m, 4), fmt_num(ci, 4))
    } else {
        fmt_num(m, 4)
    }
}

/// Which of the config's run lists this run's traffic seed is in: a
/// number read from a test run was measured where nothing may be chosen,
/// and one from a training or validation run on data a model or a
/// threshold saw.
fn seed_role(settings: &Settings) -> String {
    let seed = settings.seeds.traffic;
    let role = if settings.eval.traffic_seeds.contains(&seed) {
        "a test run (`[eval] traffic_seeds`)"
    } else if settings.train.validation_seeds.contains(&seed) {
        "a validation run (`[train] validation_seeds`): thresholds were chosen on it"
    } else if settings.train.traffic_seeds.contains(&seed) {
        "a training run (`[train] traffic_seeds`): the models were fitted on it"
    } else {
        "none of the training, validation or test runs"
    };
    format!("traffic seed {seed} is {role}")
}

/// The report of one run.
pub fn run(settings: &Settings, results: &RunResults, rows: &[SummaryRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# coid-sim run\n");
    let _ = writeln!(s, "- config: `{}`", settings.source.display());
    let _ = writeln!(
        s,
        "- scenario: `{}`, junction `{}`",
        settings.scenario.sumocfg.display(),
        settings.scenario.junction
    );
    let _ = writeln!(
        s,
        "- seeds: traffic {}, sensor {}; simulated {:.1} s in {} steps; {} instances",
        settings.seeds.traffic,
        settings.seeds.sensor,
        results.sim_end_s,
        results.n_steps,
        results.n_instances
    );
    let _ = writeln!(s, "- {}", seed_role(settings));
    let _ = writeln!(s, "{RUN_PROTOCOL}\n");
    let _ = writeln!(
        s,
        "| method | pose noise | fusion | instances | objects | matched | precision | recall | F1 | DE single (m) | DE fused (m) | DE single, covisible (m) | DE fused, covisible (m) |"
    );
    let _ = writeln!(
        s,
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in rows {
        let n = |v: f64| fmt_num(v, 4);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.key.method.as_str(),
            r.key.pose_noise.as_str(),
            r.key.fusion.as_str(),
            r.n_instances,
            r.n_objects,
            r.n_matched,
            n(r.precision),
            n(r.recall),
            n(r.f1),
            n(r.de_single_m),
            n(r.de_fused_m),
            n(r.de_single_covis_m),
            n(r.de_fused_covis_m),
        );
    }
    consistency(&mut s, settings, results);
    all_views(&mut s, rows);
    s
}

/// Fusion from every view beside the pairwise fusion, on one object set.
fn all_views(s: &mut String, rows: &[SummaryRow]) {
    let _ = writeln!(
        s,
        "\n## Fusion from every view\n\n- every (ego, real object) of a step once; pairwise: the mean of the object's pairwise fused error over the ego's instances whose peer sees it (over all its instances if none does); all views: fused from the ego's and every matched peer's detection (Eq. 14-16 with N terms)\n"
    );
    let _ = writeln!(
        s,
        "| method | pose noise | fusion | objects | DE single (m) | DE fused, pairwise (m) | DE fused, all views (m) |"
    );
    let _ = writeln!(s, "|---|---|---|---:|---:|---:|---:|");
    for r in rows {
        let n = |v: f64| fmt_num(v, 4);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} |",
            r.key.method.as_str(),
            r.key.pose_noise.as_str(),
            r.key.fusion.as_str(),
            r.n_ego_objects,
            n(r.de_single_per_ego_m),
            n(r.de_fused_pairwise_per_ego_m),
            n(r.de_fused_all_views_m),
        );
    }
}

/// The run's consistency across vehicles, per method and pose noise.
fn consistency(s: &mut String, settings: &Settings, results: &RunResults) {
    let _ = writeln!(
        s,
        "\n## Across vehicles (`multi_vehicle = \"{}\"`)\n\n{CONSISTENCY_PROTOCOL}\n",
        settings.matching.multi_vehicle.as_str()
    );
    let _ = writeln!(
        s,
        "| method | pose noise | triple chains | inconsistent share | object precision | object recall | object F1 |"
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|");
    for ((m, l), c) in &results.summary.consistency {
        let n = |v: f64| fmt_num(v, 4);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} |",
            m.as_str(),
            l.as_str(),
            c.triples.chains,
            n(c.triples.share()),
            n(c.objects.precision()),
            n(c.objects.recall()),
            n(c.objects.f1()),
        );
    }
}

/// How the consistency numbers are made.
const CONSISTENCY_PROTOCOL: &str = "- triple chains: detections x~y~z matched across three connected vehicles whose three pairs are all instances of the step; inconsistent: the pair of x and z contradicts the chain (n/a without any chain)\n\
- object precision, recall, F1: the objects the matches imply (the transitive closure of the pairs, or the synchronised assignment) scored as a clustering: every detection pair of an instance's two vehicles, same object or not, against the truth";

/// How a run's numbers are made, in one paragraph.
const RUN_PROTOCOL: &str = "- precision and recall pool the pairs of all instances; precision is n/a when the method identified no pair\n\
- displacement errors (metres, ground plane, ego frame) are means over every real object an ego detects, the same set for every method: fused = single where the method left the object unmatched, a wrong match counts as fused; `covisible`: the objects the peer detects too; `summary.csv` also has the mean over matched objects only (`de_*_matched_m`)";

/// The report of `coid eval`: the seeds, the thresholds, then every table.
pub fn eval(
    settings: &Settings,
    tables: &[(&str, &Table)],
    choices: &BTreeMap<Method, DeepChoice>,
    pooled: Option<&str>,
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# coid-sim evaluation\n");
    if let Some(scenarios) = pooled {
        let _ = writeln!(
            md,
            "- pooled over the runs of every scenario of the suite: {scenarios}"
        );
        let _ = writeln!(
            md,
            "- training runs: {:?}; validation runs: {:?} (of `{}`)",
            settings.train.traffic_seeds,
            settings.train.validation_seeds,
            settings.source.display()
        );
    } else if let Some(d) = &settings.dataset {
        let _ = writeln!(
            md,
            "- config: `{}` (methods and their settings)",
            settings.source.display()
        );
        let _ = writeln!(
            md,
            "- evaluated runs: the {} runs of the dataset `{}`, read as it gives them (not \
             simulated); the deep methods' weights: `{}`",
            d.split.as_deref().unwrap_or("test"),
            d.dir.display(),
            settings.matching.models_dir.display()
        );
        if let Some(law) = d.descriptor_law {
            let _ = writeln!(
                md,
                "- appearance vectors: the likelihood ratio exp({:.2} (cos - {:.3})) of their \
                 cosine similarity, fitted on the dataset's validation runs, multiplies `ours`'s \
                 appearance similarity, and MOGM's, RGM's and GPS+appearance Hungarian's raised \
                 to the weight validation chose (`baselines.toml`); a deep network reads them \
                 as node features when it was trained on them (`appearance_width` or \
                 `node_features` in its record)",
                law.slope, law.neutral
            );
        }
    } else {
        let _ = writeln!(md, "- config: `{}`", settings.source.display());
        let _ = writeln!(
            md,
            "- evaluated runs (traffic = sensor seed): {:?}; training runs: {:?}; validation runs: {:?}",
            settings.eval.traffic_seeds,
            settings.train.traffic_seeds,
            settings.train.validation_seeds
        );
    }
    let chosen: Vec<String> = choices.iter().map(|(m, c)| choice_text(*m, c)).collect();
    let source = match settings.matching.lambda {
        LambdaChoice::Validated => "each chosen on the validation runs by `coid train`",
        LambdaChoice::Fixed(_) => "as configured",
    };
    let _ = writeln!(
        md,
        "- thresholds lambda on the total entropy, and on each uncertainty type for Table 3 ({source}): {}",
        chosen.join(", ")
    );
    let _ = writeln!(
        md,
        "- every number is the mean over test runs, `±` the half-width of its 95% confidence interval (Student t)\n"
    );
    // The curves are plot data (101 rows per method): their file has them.
    for (name, t) in tables.iter().filter(|(name, _)| *name != "pr_curve.csv") {
        let _ = writeln!(md, "## {name}\n\n{}\n", table(t));
    }
    md
}

/// A deep method's validated choice as the summary states it.
fn choice_text(m: Method, c: &DeepChoice) -> String {
    format!(
        "{} {} (epistemic {}, aleatoric {}; decision {} at E[Y] >= {:.1}, temperature {:.2})",
        m.as_str(),
        lambda_text(c.lambdas.get(UncertaintyKind::Total)),
        lambda_text(c.lambdas.get(UncertaintyKind::Epistemic)),
        lambda_text(c.lambdas.get(UncertaintyKind::Aleatoric)),
        c.decision.as_str(),
        c.min_probability,
        c.temperature
    )
}

/// A threshold lambda as a person reads it: "none" when infinite.
fn lambda_text(lambda: f64) -> String {
    if lambda.is_infinite() {
        "none".to_owned()
    } else {
        format!("{lambda:.2}")
    }
}

/// A table in Markdown, `x ± ci` for each `x` with an `x_ci95` column
/// (a `lambda` column's infinity, "no threshold", as "none").
pub fn table(t: &Table) -> String {
    let names: Vec<&String> = t.columns.iter().map(|(n, _)| n).collect();
    let shown: Vec<usize> = (0..names.len())
        .filter(|&k| !names[k].ends_with("_ci95"))
        .collect();
    let cell = |k: usize, r: usize| -> String {
        match &t.columns[k].1 {
            TableColumn::Text(v) => v[r].clone(),
            TableColumn::Count(v) => v[r].to_string(),
            TableColumn::Flag(v) => v[r].to_string(),
            TableColumn::Vectors(v) => format!("[{} values]", v[r].len()),
            TableColumn::Number(v) if names[k] == "lambda" => lambda_text(v[r]),
            TableColumn::Number(v) => match t.column(&format!("{}_ci95", names[k])) {
                Some(TableColumn::Number(c)) => with_ci(v[r], c[r]),
                _ => fmt_num(v[r], 4),
            },
        }
    };
    let mut s = format!(
        "| {} |\n|{}\n",
        shown
            .iter()
            .map(|&k| names[k].as_str())
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(shown.len())
    );
    for r in 0..t.height() {
        let cells: Vec<String> = shown.iter().map(|&k| cell(k, r)).collect();
        let _ = writeln!(s, "| {} |", cells.join(" | "));
    }
    s
}

/// The report of a batch: `header` (what was run), then the aggregate.
pub fn batch(rows: &[AggregateRow], header: &str) -> String {
    let mut md = format!("# coid-sim batch\n\n{header}\n\n");
    let _ = writeln!(
        md,
        "| method | pose noise | fusion | runs | instances | precision | recall | F1 | DE single (m) | DE fused (m) | DE fused, covisible (m) |"
    );
    let _ = writeln!(md, "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let pm = |r: &AggregateRow, m: Metric| {
        let (mean, ci) = r.get(m);
        with_ci(mean, ci)
    };
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.key.method.as_str(),
            r.key.pose_noise.as_str(),
            r.key.fusion.as_str(),
            r.n_runs,
            r.n_instances,
            pm(r, Metric::Precision),
            pm(r, Metric::Recall),
            pm(r, Metric::F1),
            pm(r, Metric::DeSingle),
            pm(r, Metric::DeFused),
            pm(r, Metric::DeFusedCovisible)
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_show_intervals_beside_their_means() {
        let mut t = Table::default();
        t.text("method", vec!["ours".into(), "rgm".into()]);
        t.number("f1", vec![0.5, f64::NAN]);
        t.number("f1_ci95", vec![0.01, f64::NAN]);
        t.count("n_runs", vec![2, 2]);
        assert_eq!(
            table(&t),
            "| method | f1 | n_runs |\n|---|---|---|\n| ours | 0.5000 ± 0.0100 | 2 |\n| rgm | n/a | 2 |\n"
        );
    }
}
