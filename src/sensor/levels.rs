//! Pose-noise levels' names: the three built in (`none`, `rtk`, `gps`) and
//! any a configuration or a dataset defines (`[pose_noise] levels`), so
//! that a sweep over GNSS sigmas needs a config and no code.

use std::sync::RwLock;

/// The built-in levels, in the order results are reported at.
const BUILT_IN: [&str; 3] = ["none", "rtk", "gps"];

/// The names defined beyond the built-in ones, in the order this process
/// first met them (a name is leaked once: levels are few).
static DEFINED: RwLock<Vec<&'static str>> = RwLock::new(Vec::new());

/// Longest name of a level.
const MAX_NAME: usize = 32;

/// A pose-noise level's name. Copy, and ordered as results are reported:
/// the built-in levels first (none, rtk, gps), then defined ones in the
/// order they were first named (a configuration's order).
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PoseNoiseLabel(u32);

impl PoseNoiseLabel {
    /// Perfect self-localisation.
    pub const NONE: Self = Self(0);
    /// RTK-class GNSS: 0.2 m / 0.2 deg by default.
    pub const RTK: Self = Self(1);
    /// Plain GPS as in the DMGM data: 1.2 m / 0.2 deg by default.
    pub const GPS: Self = Self(2);

    /// The level called `name`: a built-in one, or one defined by it
    /// (1 to 32 of `a-z`, `0-9`, `.`, `-`, `_`, starting with a letter or
    /// digit).
    ///
    /// # Errors
    /// `name` is not such a name.
    pub fn named(name: &str) -> Result<Self, String> {
        if let Some(k) = BUILT_IN.iter().position(|b| *b == name) {
            return Ok(Self(k as u32));
        }
        let good = (1..=MAX_NAME).contains(&name.len())
            && name.starts_with(|c: char| c.is_ascii_lowercase() || c.is_ascii_digit())
            && name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || "._-".contains(c));
        if !good {
            return Err(format!(
                "'{name}' is no pose-noise level's name (1 to {MAX_NAME} of a-z, 0-9, '.', '-', \
                 '_', starting with a letter or digit)"
            ));
        }
        let mut defined = DEFINED
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let k = match defined.iter().position(|d| *d == name) {
            Some(k) => k,
            None => {
                defined.push(Box::leak(name.to_owned().into_boxed_str()));
                defined.len() - 1
            }
        };
        Ok(Self((BUILT_IN.len() + k) as u32))
    }

    /// The name used in configs, command lines and results.
    pub fn as_str(self) -> &'static str {
        let k = self.0 as usize;
        match BUILT_IN.get(k) {
            Some(name) => name,
            None => DEFINED
                .read()
                .unwrap_or_else(std::sync::PoisonError::into_inner)[k - BUILT_IN.len()],
        }
    }

    /// Whether the level is one of the three built in.
    pub fn is_built_in(self) -> bool {
        (self.0 as usize) < BUILT_IN.len()
    }

    /// The level's part of a pose-noise stream name (frozen: changing it
    /// changes every result): 0, 1, 2 for the built-in levels, a hash of
    /// the name past them for a defined one (the same in every process,
    /// whatever order names were met in).
    pub(crate) fn stream_code(self) -> u64 {
        if self.is_built_in() {
            u64::from(self.0)
        } else {
            crate::rng::hash_str(self.as_str()).max(BUILT_IN.len() as u64)
        }
    }
}

/// As the enum it replaces printed its variants (`None`, `Rtk`, `Gps`):
/// settings' digests stay what they were; a defined level as
/// `Named("<name>")`.
impl std::fmt::Debug for PoseNoiseLabel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            0 => f.write_str("None"),
            1 => f.write_str("Rtk"),
            2 => f.write_str("Gps"),
            _ => write!(f, "Named({:?})", self.as_str()),
        }
    }
}

impl std::str::FromStr for PoseNoiseLabel {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Self::named(s)
    }
}

impl strum::VariantNames for PoseNoiseLabel {
    const VARIANTS: &'static [&'static str] = &BUILT_IN;
}

impl crate::label::Label for PoseNoiseLabel {
    fn label(self) -> &'static str {
        self.as_str()
    }

    fn unknown(what: &str, given: &str) -> String {
        match Self::named(given) {
            Err(why) => why,
            Ok(_) => format!("unknown {what} '{given}'"),
        }
    }
}

impl serde::Serialize for PoseNoiseLabel {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> serde::Deserialize<'de> for PoseNoiseLabel {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = <String as serde::Deserialize>::deserialize(d)?;
        crate::label::parse::<Self>("pose-noise level", &s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn golden_pose_noise_stream_codes_and_labels() {
        // Part of every pose-noise stream's name: frozen.
        let levels = [
            PoseNoiseLabel::NONE,
            PoseNoiseLabel::RTK,
            PoseNoiseLabel::GPS,
        ];
        let codes: Vec<u64> = levels.iter().map(|l| l.stream_code()).collect();
        assert_eq!(codes, vec![0, 1, 2]);
        let labels: Vec<&str> = levels.iter().map(|l| l.as_str()).collect();
        assert_eq!(labels, vec!["none", "rtk", "gps"]);
        let debug: Vec<String> = levels.iter().map(|l| format!("{l:?}")).collect();
        assert_eq!(debug, ["None", "Rtk", "Gps"]);
    }

    #[test]
    fn defined_levels_keep_their_names_and_come_after_the_built_in_ones() {
        let b = PoseNoiseLabel::named("sweep-b.2").unwrap();
        let a = PoseNoiseLabel::named("sweep-a_1").unwrap();
        assert_eq!(PoseNoiseLabel::named("sweep-b.2"), Ok(b));
        assert_eq!((a.as_str(), b.as_str()), ("sweep-a_1", "sweep-b.2"));
        assert!(PoseNoiseLabel::GPS < b && b < a, "met first, ordered first");
        assert_eq!(format!("{a:?}"), "Named(\"sweep-a_1\")");
        assert!(!a.is_built_in() && PoseNoiseLabel::RTK.is_built_in());
        // The stream code is the name's, whatever order names were met in.
        assert_eq!(a.stream_code(), crate::rng::hash_str("sweep-a_1").max(3));
        assert_ne!(a.stream_code(), b.stream_code());
        assert_eq!("gps".parse::<PoseNoiseLabel>(), Ok(PoseNoiseLabel::GPS));
        for bad in ["", "GPS", "-x", "a b", &"x".repeat(33)] {
            let e = crate::label::parse::<PoseNoiseLabel>("pose-noise level", bad).unwrap_err();
            assert!(e.contains("is no pose-noise level's name"), "{e}");
        }
    }
}
