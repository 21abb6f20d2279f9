//! Validation of `[appearance]`: the vehicle catalogue (read and checked
//! here, the shipped one unless a file is named) and the
//! re-identification descriptor's width and targets.

use std::sync::Arc;

use super::ConfigError;
use super::check::{Checker, num};
use super::raw::{RawAppearance, RawRate};
use crate::sensor::AppearanceSettings;
use crate::sensor::reid::{ReidSettings, ReidTarget};
use crate::traffic::catalogue::Catalogue;

/// Descriptors wider than this are refused: each detection carries one.
const MAX_WIDTH: usize = 4096;

pub(super) fn appearance(c: &Checker, a: RawAppearance) -> Result<AppearanceSettings, ConfigError> {
    let catalogue = match a.vehicles.as_str() {
        "demand" => None,
        "catalogue" => Some(Arc::new(catalogue(c, &a.catalogue)?)),
        other => {
            return Err(c.invalid(
                "appearance.vehicles",
                format!("must be \"demand\" or \"catalogue\", got \"{other}\""),
            ));
        }
    };
    let reid = match a.descriptor.as_str() {
        "none" => {
            // A file that states the descriptor's figures but not the
            // descriptor meant to use it; one that says "none" as well
            // (the defaults file itself) turned it off on purpose.
            let set = ["appearance.width", "appearance.rank1", "appearance.auroc"]
                .into_iter()
                .find(|k| c.stated.contains(*k))
                .filter(|_| !c.stated.contains("appearance.descriptor"));
            if let Some(key) = set {
                return Err(c.invalid(
                    key,
                    "sets the re-identification descriptor, which this configuration leaves \
                     out (set [appearance] descriptor = \"reid\" too)"
                        .into(),
                ));
            }
            None
        }
        "reid" => Some(reid(c, &a)?),
        other => {
            return Err(c.invalid(
                "appearance.descriptor",
                format!("must be \"none\" or \"reid\", got \"{other}\""),
            ));
        }
    };
    Ok(AppearanceSettings { catalogue, reid })
}

fn catalogue(c: &Checker, path: &str) -> Result<Catalogue, ConfigError> {
    if path.is_empty() {
        return Ok(Catalogue::shipped());
    }
    let file = c.resolve(std::path::Path::new(path));
    let text = std::fs::read_to_string(&file).map_err(|e| {
        c.invalid(
            "appearance.catalogue",
            format!("cannot read {}: {e}", file.display()),
        )
    })?;
    Catalogue::parse(&text)
        .map_err(|e| c.invalid("appearance.catalogue", format!("{}: {e}", file.display())))
}

fn reid(c: &Checker, a: &RawAppearance) -> Result<ReidSettings, ConfigError> {
    if !(2..=MAX_WIDTH).contains(&a.width) {
        return Err(c.invalid(
            "appearance.width",
            format!("must be in [2, {MAX_WIDTH}], got {}", a.width),
        ));
    }
    if !(a.rank1 > 0.0 && a.rank1 < 1.0) {
        return Err(c.invalid(
            "appearance.rank1",
            format!("must be a rate in (0, 1), got {}", num(a.rank1)),
        ));
    }
    let auroc = match &a.auroc {
        RawRate::Word(w) if w == "free" => None,
        RawRate::Value(v) if *v > 0.5 && *v < 1.0 => Some(*v),
        RawRate::Value(v) => {
            return Err(c.invalid(
                "appearance.auroc",
                format!("must be in (0.5, 1) or \"free\", got {}", num(*v)),
            ));
        }
        RawRate::Word(w) => {
            return Err(c.invalid(
                "appearance.auroc",
                format!("must be in (0.5, 1) or \"free\", got \"{w}\""),
            ));
        }
    };
    Ok(ReidSettings {
        width: a.width,
        target: ReidTarget {
            rank1: a.rank1,
            auroc,
        },
        calibration: None,
    })
}
