//! Labels: the names small enums carry in configs, on the command line and
//! in result files (`ours`, `gps`, `aligned`, ...). An enum declared with
//! [`label_enum!`](crate::label_enum) states its labels once, with strum's
//! `#[strum(...)]` attributes; the macro derives strum's `EnumString`,
//! `IntoStaticStr`, `VariantNames` and `VariantArray` and adds `as_str` and
//! a serde `Deserialize` through the same `FromStr`, so a label table is
//! never written twice.

/// What every labelled enum offers.
pub trait Label: Copy + std::str::FromStr + strum::VariantNames + 'static {
    /// The enum's label.
    fn label(self) -> &'static str;

    /// "unknown <what> 'x' (expected one of: a, b, c)".
    fn unknown(what: &str, given: &str) -> String {
        format!(
            "unknown {what} '{given}' (expected one of: {})",
            Self::VARIANTS.join(", ")
        )
    }
}

/// Labels that no longer exist, by kind: `(what, old label, what to
/// write instead)`. A config or command line naming one is refused with
/// its replacement, in one line.
const RENAMED: &[(&str, &str, &str)] = &[(
    "method",
    "ours-noprior",
    "'coid' (the paper's network on the paper's inputs: no GPS pose and, \
     unlike 'ours-noprior', no heading)",
)];

/// Parses a label, or says which labels exist (or what a renamed one is
/// called now).
pub fn parse<T: Label>(what: &str, given: &str) -> Result<T, String> {
    given.parse().map_err(|_| {
        match RENAMED
            .iter()
            .find(|&&(kind, old, _)| kind == what && old == given)
        {
            Some((_, _, now)) => format!("{what} '{given}' was renamed: write {now}"),
            None => T::unknown(what, given),
        }
    })
}

/// Declares a labelled enum: `label_enum! { "what"; <enum> }` with the
/// labels in `#[strum(...)]` attributes; `what` names the kind of label in
/// error messages. The enum is `Copy`, ordered in declaration order (the
/// order of result rows), and implements [`Label`].
#[macro_export]
macro_rules! label_enum {
    ($what:expr; $(#[$meta:meta])* $vis:vis enum $name:ident { $($body:tt)* }) => {
        #[derive(
            Clone,
            Copy,
            Debug,
            PartialEq,
            Eq,
            Hash,
            PartialOrd,
            Ord,
            strum::EnumString,
            strum::IntoStaticStr,
            strum::VariantNames,
            strum::VariantArray,
        )]
        $(#[$meta])*
        $vis enum $name { $($body)* }
        $crate::label_enum!(@impl $name, $what);
    };
    (@impl $t:ty, $what:expr) => {
        impl $crate::label::Label for $t {
            fn label(self) -> &'static str {
                self.into()
            }
        }

        impl $t {
            /// The label used in configs, command lines and results.
            pub fn as_str(self) -> &'static str {
                self.into()
            }
        }

        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.as_str())
            }
        }

        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = <String as serde::Deserialize>::deserialize(d)?;
                $crate::label::parse::<$t>($what, &s).map_err(serde::de::Error::custom)
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::label_enum! { "colour";
        enum Colour {
            #[strum(serialize = "red")]
            Red,
            #[strum(serialize = "dark-blue")]
            DarkBlue,
        }
    }

    #[derive(Debug, serde::Deserialize)]
    struct Holder {
        c: Colour,
    }

    #[test]
    fn labels_round_trip_and_unknown_ones_are_listed() {
        assert_eq!(Colour::DarkBlue.as_str(), "dark-blue");
        assert_eq!(parse::<Colour>("colour", "red"), Ok(Colour::Red));
        let e = parse::<Colour>("colour", "green").unwrap_err();
        assert_eq!(
            e,
            "unknown colour 'green' (expected one of: red, dark-blue)"
        );
        let h: Holder = toml::from_str("c = \"dark-blue\"").unwrap();
        assert_eq!(h.c, Colour::DarkBlue);
        let e = toml::from_str::<Holder>("c = \"green\"").unwrap_err();
        assert!(e.to_string().contains("unknown colour 'green'"), "{e}");
    }
}

/// `n` and a noun, plural unless `n` is 1: "1 run", "3 runs", "2
/// deliveries" (`noun` in the singular, its plural regular).
pub fn counted(n: impl Into<u64>, noun: &str) -> String {
    let n = n.into();
    if n == 1 {
        return format!("1 {noun}");
    }
    match noun.strip_suffix('y') {
        Some(stem) if !stem.ends_with(['a', 'e', 'o', 'u']) => format!("{n} {stem}ies"),
        _ => format!("{n} {noun}s"),
    }
}

#[cfg(test)]
mod counted_tests {
    use super::counted;

    #[test]
    fn one_is_singular_and_every_other_count_plural() {
        assert_eq!(counted(1u64, "run"), "1 run");
        assert_eq!(counted(0u64, "run"), "0 runs");
        assert_eq!(counted(2u64, "validation run"), "2 validation runs");
        assert_eq!(counted(2u64, "delivery"), "2 deliveries");
        assert_eq!(counted(3u64, "day"), "3 days");
    }
}
