//! The checks every section's validation uses: one error type per key,
//! numbers in messages that stay readable, seeds SUMO accepts, lists
//! without repeats, paths relative to the config file.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use super::ConfigError;

/// The largest traffic seed: SUMO's `--seed` is a signed 32-bit int.
pub const MAX_TRAFFIC_SEED: u64 = i32::MAX as u64;

/// A speed error's standard deviation at most (m/s): far beyond any
/// detector's or receiver's, and far from overflowing a speed.
pub const MAX_SPEED_SIGMA_MPS: f64 = 100.0;

/// A raw field and its key, the key made from the section and the field's
/// own name (never spelled by hand): `field!("sensor", s.colour_sigma)` is
/// `("sensor.colour_sigma", s.colour_sigma)`.
macro_rules! field {
    ($section:literal, $raw:ident . $name:ident) => {
        (concat!($section, ".", stringify!($name)), $raw.$name)
    };
}
pub(super) use field;

/// Names the file in validation errors and resolves its relative paths.
pub(super) struct Checker<'a> {
    pub(super) path: &'a Path,
    /// The keys the user's file states (`section.key`), so that a
    /// conflict between two keys is reported under the one the user wrote.
    pub(super) stated: &'a BTreeSet<String>,
}

/// A number in a message: as written for ordinary values, in scientific
/// notation for huge or tiny ones (never 300 digits).
pub(super) fn num(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-4..1e7).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl Checker<'_> {
    pub(super) fn invalid(&self, key: &'static str, message: String) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_owned(),
            key,
            message,
        }
    }

    pub(super) fn positive(&self, (key, v): (&'static str, f64)) -> Result<(), ConfigError> {
        if v > 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be a positive number, got {}", num(v))))
        }
    }

    pub(super) fn non_negative(&self, (key, v): (&'static str, f64)) -> Result<(), ConfigError> {
        if v >= 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be >= 0, got {}", num(v))))
        }
    }

    /// A detector's box errors (`<section>.heading_sigma_deg`,
    /// `heading_flip_prob`, `speed_sigma_mps`), checked.
    pub(super) fn box_errors(
        &self,
        section: &str,
        [heading_sigma_deg, heading_flip_prob, speed_sigma_mps]: [f64; 3],
    ) -> Result<crate::sensor::boxes::BoxErrors, ConfigError> {
        // An error ends the command: the key's few bytes are leaked once.
        let key = |name: &str| -> &'static str {
            Box::leak(format!("{section}.{name}").into_boxed_str())
        };
        self.within((key("heading_sigma_deg"), heading_sigma_deg), 0.0, 360.0)?;
        self.fraction((key("heading_flip_prob"), heading_flip_prob))?;
        self.within(
            (key("speed_sigma_mps"), speed_sigma_mps),
            0.0,
            MAX_SPEED_SIGMA_MPS,
        )?;
        Ok(crate::sensor::boxes::BoxErrors {
            heading_sigma_rad: heading_sigma_deg.to_radians(),
            heading_flip_prob,
            speed_sigma_mps,
        })
    }

    /// `v` in `lo..=hi` (`NaN` never is).
    pub(super) fn within(
        &self,
        (key, v): (&'static str, f64),
        lo: f64,
        hi: f64,
    ) -> Result<(), ConfigError> {
        if (lo..=hi).contains(&v) {
            Ok(())
        } else {
            Err(self.invalid(
                key,
                format!("must be in [{}, {}], got {}", num(lo), num(hi), num(v)),
            ))
        }
    }

    pub(super) fn fraction(&self, (key, v): (&'static str, f64)) -> Result<(), ConfigError> {
        if (0.0..=1.0).contains(&v) {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be in [0, 1], got {}", num(v))))
        }
    }

    /// A traffic seed SUMO accepts (`--seed` is a 32-bit int).
    pub(super) fn traffic_seed(&self, key: &'static str, seed: u64) -> Result<(), ConfigError> {
        if seed <= MAX_TRAFFIC_SEED {
            Ok(())
        } else {
            Err(self.invalid(
                key,
                format!("{seed} is beyond SUMO's seed range (0 to {MAX_TRAFFIC_SEED})"),
            ))
        }
    }

    /// A list of run seeds: each in SUMO's range, none twice.
    pub(super) fn seed_list(&self, key: &'static str, seeds: &[u64]) -> Result<(), ConfigError> {
        for (k, &s) in seeds.iter().enumerate() {
            self.traffic_seed(key, s)?;
            if seeds[..k].contains(&s) {
                return Err(self.invalid(key, format!("seed {s} is listed twice")));
            }
        }
        Ok(())
    }

    /// `list` sorted (output rows come in a fixed order whatever order the
    /// user listed things in), refused when it names something twice.
    pub(super) fn distinct<T: Ord + crate::label::Label>(
        &self,
        key: &'static str,
        mut list: Vec<T>,
    ) -> Result<Vec<T>, ConfigError> {
        list.sort();
        match list.windows(2).find(|w| w[0] == w[1]) {
            Some(w) => Err(self.invalid(key, format!("lists '{}' twice", w[0].label()))),
            None => Ok(list),
        }
    }

    /// Of two keys in conflict, the one to report: the one the user's
    /// file states (the first when it states both or neither).
    pub(super) fn blame(
        &self,
        first: &'static str,
        second: &'static str,
    ) -> (&'static str, &'static str) {
        if !self.stated.contains(first) && self.stated.contains(second) {
            (second, first)
        } else {
            (first, second)
        }
    }

    /// A path relative to the config file's folder.
    pub(super) fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_owned()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }
}
