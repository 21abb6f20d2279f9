//! `coid score`'s side of the export: a matches file's rows checked
//! against the configuration's runs and levels, and turned into each
//! scored run's [`ExternalMatches`].

use std::collections::{BTreeMap, BTreeSet};

use super::{ExportRun, Split};
use crate::evaluate::ExternalMatches;
use crate::matching::{Correspondence, binary_entropy_bits};
use crate::report::MatchRow;
use crate::sensor::PoseNoiseLabel;

/// A matches file's rows as each scored run's [`ExternalMatches`], keyed
/// by run index (every run of `split` has an entry, empty when the file
/// names none of its instances), and how many rows name runs of the other
/// splits (left out: a matcher may well have matched every exported run).
/// Refused, with the reason in one line, when a row names a run this
/// configuration does not have, a level that is not configured, or a node
/// already matched in its instance and level, or carries a probability
/// outside [0, 1] or an uncertainty that is not a finite number of bits;
/// or when no row names a run of `split`.
pub fn external_matches(
    rows: &[MatchRow],
    runs: &[ExportRun],
    split: Split,
    levels: &[PoseNoiseLabel],
) -> Result<(BTreeMap<usize, ExternalMatches>, usize), String> {
    let mut out: BTreeMap<usize, ExternalMatches> = runs
        .iter()
        .filter(|r| r.split == split)
        .map(|r| (r.index, ExternalMatches::default()))
        .collect();
    let mut other_splits = 0;
    let mut used: BTreeSet<MatchedNode> = BTreeSet::new();
    for (k, row) in rows.iter().enumerate() {
        let line = k + 1;
        let run = usize::try_from(row.run).unwrap_or(usize::MAX);
        let Some(matches) = out.get_mut(&run) else {
            if run < runs.len() {
                other_splits += 1;
                continue;
            }
            return Err(format!(
                "row {line} names run {run}, but this configuration has {} runs",
                runs.len()
            ));
        };
        let at: Vec<PoseNoiseLabel> = match &row.pose_noise {
            None => levels.to_vec(),
            Some(label) => match levels.iter().find(|l| l.as_str() == label) {
                Some(&l) => vec![l],
                None => {
                    let known: Vec<&str> = levels.iter().map(|l| l.as_str()).collect();
                    return Err(format!(
                        "row {line} names pose-noise level '{label}', not one of this configuration's ({})",
                        known.join(", ")
                    ));
                }
            },
        };
        let c = correspondence(row).map_err(|why| format!("row {line}: {why}"))?;
        let instance = usize::try_from(row.instance).unwrap_or(usize::MAX);
        for level in at {
            for (side, node) in [(0, c.a), (1, c.b)] {
                let matched = MatchedNode {
                    run,
                    instance,
                    level,
                    side,
                    node,
                };
                if !used.insert(matched) && matches.repeated.is_none() {
                    // Refused once the instance's nodes are known to
                    // exist: a row naming a node the vehicle lacks is
                    // refused as that first.
                    matches.repeated = Some((
                        (instance, level),
                        format!(
                            "row {line} matches node {node} of the {} vehicle of run {run}, instance {instance} at level {} a second time",
                            ["first", "second"][usize::from(side)],
                            level.as_str()
                        ),
                    ));
                }
            }
            matches
                .by_instance
                .entry((instance, level))
                .or_default()
                .push(c);
        }
    }
    if rows.len() == other_splits {
        return Err(format!(
            "it names no {} run{}",
            split.as_str(),
            match other_splits {
                0 => String::new(),
                1 => " (its one row names a run of another split)".to_owned(),
                n => format!(" (its {n} rows name runs of other splits)"),
            }
        ));
    }
    for m in out.values_mut() {
        for list in m.by_instance.values_mut() {
            list.sort_by_key(|c| c.a);
        }
    }
    Ok((out, other_splits))
}

/// A node a matches file has matched: a node of one vehicle (`side` 0:
/// the first, 1: the second) of an instance at one level, at most once.
#[derive(PartialEq, Eq, PartialOrd, Ord)]
struct MatchedNode {
    run: usize,
    instance: usize,
    level: PoseNoiseLabel,
    side: u8,
    node: usize,
}

/// A row's correspondence, its probability 1 and its uncertainty the
/// binary entropy of its probability unless it says otherwise.
fn correspondence(row: &MatchRow) -> Result<Correspondence, String> {
    let probability = row.probability.unwrap_or(1.0);
    if !(0.0..=1.0).contains(&probability) {
        return Err(format!("probability {probability} is not in [0, 1]"));
    }
    let uncertainty = row
        .uncertainty
        .unwrap_or_else(|| binary_entropy_bits(probability));
    if !(0.0..=1.0).contains(&uncertainty) {
        return Err(format!(
            "uncertainty {uncertainty} is not in [0, 1] (binary entropy in bits)"
        ));
    }
    let node = |v: u64| usize::try_from(v).map_err(|_| format!("node {v} is out of range"));
    Ok(Correspondence {
        a: node(row.a)?,
        b: node(row.b)?,
        probability,
        uncertainty,
    })
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::config::Settings;
    use crate::export::runs;

    fn row(run: usize, a: u64, b: u64, level: Option<&str>) -> MatchRow {
        MatchRow {
            run: run as u64,
            instance: 3,
            pose_noise: level.map(str::to_owned),
            a,
            b,
            probability: None,
            uncertainty: None,
        }
    }

    /// Runs are numbered train, validation, test; a row without a level
    /// holds at every level, as a certain match; a node may be matched
    /// once per level.
    #[test]
    fn runs_are_numbered_by_split_and_rows_hold_per_level() {
        let s = Settings::from_toml(
            "[eval]\ntraffic_seeds = [1, 2]\n",
            Path::new("/tmp/somewhere/user.toml"),
        )
        .unwrap();
        let all = runs(&s).unwrap();
        assert!(all.iter().enumerate().all(|(k, r)| r.index == k));
        let splits: Vec<Split> = all.iter().map(|r| r.split).collect();
        assert!(splits.is_sorted() && splits.contains(&Split::Validation));
        let test: Vec<&ExportRun> = all.iter().filter(|r| r.split == Split::Test).collect();
        assert_eq!(test.iter().map(|r| r.seed).collect::<Vec<_>>(), [1, 2]);
        let t = test[0].index;
        let levels = [PoseNoiseLabel::NONE, PoseNoiseLabel::GPS];
        let (m, _) = external_matches(&[row(t, 1, 2, None)], &all, Split::Test, &levels).unwrap();
        assert_eq!(m.len(), 2);
        let at_gps = &m[&t].by_instance[&(3, PoseNoiseLabel::GPS)];
        assert_eq!((at_gps[0].probability, at_gps[0].uncertainty), (1.0, 0.0));
        assert_eq!(m[&t].by_instance.len(), 2);
        let fine = [row(t, 1, 2, Some("gps")), row(t, 1, 2, Some("none"))];
        assert!(external_matches(&fine, &all, Split::Test, &levels).is_ok());
        // A node matched twice is refused once its instance is known to
        // have it (ExternalMatches::check).
        let twice = [row(t, 1, 2, Some("gps")), row(t, 0, 2, None)];
        let (m, _) = external_matches(&twice, &all, Split::Test, &levels).unwrap();
        let (key, e) = m[&t].repeated.clone().unwrap();
        assert_eq!(key, (3, PoseNoiseLabel::GPS));
        assert!(e.contains("node 2 of the second vehicle"), "{e}");
        // Rows of the other splits are left out and counted; a file with
        // only such rows names no test run.
        let validation = all.iter().find(|r| r.split == Split::Validation).unwrap();
        let other = row(validation.index, 0, 0, None);
        let (m, left_out) = external_matches(
            &[other.clone(), row(t, 1, 2, None)],
            &all,
            Split::Test,
            &levels,
        )
        .unwrap();
        assert_eq!((left_out, m[&t].by_instance.len()), (1, 2));
        let e = external_matches(&[other], &all, Split::Test, &levels).unwrap_err();
        assert!(e.contains("names no test run"), "{e}");
    }
}
