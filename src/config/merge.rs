//! Merging the user's file over the defaults: the defaults' relative
//! paths anchored at the installation, every key the user lacks added
//! (`[connected]` replaced whole), and the keys the user's file states.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::path::Path;

use toml::de::{DeTable, DeValue};

use super::defaults_dir;

/// Every key a TOML table states, as `section.key` (nested tables joined
/// by dots).
pub(super) fn stated_keys(table: &DeTable<'_>, prefix: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (key, value) in table {
        let name = format!("{prefix}{}", key.get_ref());
        if let DeValue::Table(t) = value.get_ref() {
            out.extend(stated_keys(t, &format!("{name}.")));
        }
        out.insert(name);
    }
    out
}

/// Makes the defaults' relative paths absolute (anchored at
/// [`defaults_dir`]), so they mean the same from any user's folder.
pub(super) fn anchor_default_paths(defaults: &mut DeTable<'_>) {
    for (section, key) in [("scenario", "sumocfg"), ("matching", "models_dir")] {
        let Some(DeValue::Table(t)) = defaults.get_mut(section).map(|v| v.get_mut()) else {
            continue;
        };
        if let Some(v) = t.get_mut(key)
            && let DeValue::String(s) = v.get_mut()
            && Path::new(s.as_ref()).is_relative()
        {
            let abs = defaults_dir().join(s.as_ref());
            *s = Cow::Owned(abs.to_string_lossy().into_owned());
        }
    }
}

/// Adds every key of `defaults` that `user` lacks, recursing into tables
/// both have (except `[connected]`, which the user's replaces whole).
pub(super) fn merge_under<'i>(user: &mut DeTable<'i>, defaults: DeTable<'i>) {
    for (key, value) in defaults {
        match user.get_mut(key.get_ref().as_ref()) {
            None => {
                user.insert(key, value);
            }
            Some(mine) => {
                if key.get_ref() == "connected" {
                    continue;
                }
                if let (DeValue::Table(mine), DeValue::Table(theirs)) =
                    (mine.get_mut(), value.into_inner())
                {
                    merge_under(mine, theirs);
                }
            }
        }
    }
}
