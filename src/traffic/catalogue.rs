//! A vehicle catalogue in the way CARLA's blueprint library has one:
//! models with their dimensions, a class, the paints they come in and a
//! share of their class's fleet (`[appearance] vehicles = "catalogue"`).
//! Each vehicle draws a model of its class and a paint of that model from
//! its id and the traffic seed, so a road user keeps its look at every
//! step and two runs of one seed agree.
//!
//! The shipped catalogue is `configs/catalogue/vehicles.toml` (its sources beside
//! the values); a user's own is a file of the same shape.

use std::collections::BTreeMap;

use serde::Deserialize;

use super::ObjectClass;
use crate::rng::{self, Purpose};

/// The shipped catalogue's text (`configs/catalogue/vehicles.toml`).
pub const SHIPPED_CATALOGUE_TOML: &str = include_str!("../../configs/catalogue/vehicles.toml");

/// One paint a model comes in.
#[derive(Clone, Debug, PartialEq)]
pub struct Paint {
    pub name: String,
    pub rgb: [u8; 3],
    /// Its share among the model's paints (the shares of a palette sum to
    /// 1).
    pub share: f64,
}

/// One model of the catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct VehicleModel {
    pub name: String,
    pub class: ObjectClass,
    /// Length, width (without mirrors) and height, metres.
    pub size_m: [f64; 3],
    /// Its share of its class's fleet (the shares of a class sum to 1).
    pub share: f64,
    pub paints: Vec<Paint>,
}

/// The models vehicles are drawn from.
#[derive(Clone, Debug, PartialEq)]
pub struct Catalogue {
    pub models: Vec<VehicleModel>,
}

/// What is wrong with a catalogue file, said once.
#[derive(Debug, thiserror::Error)]
pub enum CatalogueError {
    #[error("the catalogue is not valid TOML of its shape: {0}")]
    Toml(String),
    #[error("catalogue model '{model}': {why}")]
    Model { model: String, why: String },
    #[error("catalogue palette '{palette}': {why}")]
    Palette { palette: String, why: String },
    #[error("the catalogue has no model")]
    Empty,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCatalogue {
    palettes: BTreeMap<String, Vec<RawPaint>>,
    models: Vec<RawModel>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPaint {
    name: String,
    rgb: [u8; 3],
    share: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    name: String,
    class: ObjectClass,
    length_m: f64,
    width_m: f64,
    height_m: f64,
    share: f64,
    palette: String,
    #[allow(dead_code)]
    source: String,
}

/// Shares that sum to 1 within this.
const SHARE_TOLERANCE: f64 = 1e-6;

impl Catalogue {
    /// The shipped catalogue.
    pub fn shipped() -> Self {
        Self::parse(SHIPPED_CATALOGUE_TOML).expect("the shipped catalogue is valid")
    }

    /// Reads a catalogue: every model names a palette the file has, its
    /// sizes are positive, it is not a pedestrian, and the shares of each
    /// class and of each palette are positive and sum to 1.
    pub fn parse(text: &str) -> Result<Self, CatalogueError> {
        let raw: RawCatalogue =
            toml::from_str(text).map_err(|e| CatalogueError::Toml(e.message().to_owned()))?;
        for (name, paints) in &raw.palettes {
            check_shares(paints.iter().map(|p| p.share)).map_err(|why| {
                CatalogueError::Palette {
                    palette: name.clone(),
                    why,
                }
            })?;
        }
        let mut models = Vec::with_capacity(raw.models.len());
        for m in raw.models {
            let bad = |why: String| CatalogueError::Model {
                model: m.name.clone(),
                why,
            };
            let size_m = [m.length_m, m.width_m, m.height_m];
            if size_m
                .iter()
                .any(|v| !(v.is_finite() && *v > 0.0 && *v < 30.0))
            {
                return Err(bad(format!(
                    "length, width and height must be in (0, 30) m, not {size_m:?}"
                )));
            }
            if m.class == ObjectClass::Pedestrian {
                return Err(bad("pedestrians are not vehicles of a catalogue".into()));
            }
            let Some(paints) = raw.palettes.get(&m.palette) else {
                let known: Vec<&str> = raw.palettes.keys().map(String::as_str).collect();
                return Err(bad(format!(
                    "no palette '{}' (the file has: {})",
                    m.palette,
                    known.join(", ")
                )));
            };
            models.push(VehicleModel {
                name: m.name,
                class: m.class,
                size_m,
                share: m.share,
                paints: paints
                    .iter()
                    .map(|p| Paint {
                        name: p.name.clone(),
                        rgb: p.rgb,
                        share: p.share,
                    })
                    .collect(),
            });
        }
        if models.is_empty() {
            return Err(CatalogueError::Empty);
        }
        for class in ObjectClass::ALL {
            let shares = models.iter().filter(|m| m.class == class).map(|m| m.share);
            if shares.clone().count() > 0 {
                check_shares(shares).map_err(|why| CatalogueError::Model {
                    model: format!("every {}", class.as_str()),
                    why: format!("the fleet shares of a class: {why}"),
                })?;
            }
        }
        Ok(Self { models })
    }

    /// The model (its index) and paint of vehicle `id` of `class`, drawn
    /// by its id and `traffic_seed` from the models of its class by their
    /// shares, then from the model's paints; `None` when the catalogue has
    /// no model of the class (pedestrians, or a class left out).
    pub fn draw(&self, traffic_seed: u64, id: &str, class: ObjectClass) -> Option<(u16, &Paint)> {
        let id_hash = rng::hash_str(id);
        let of_class: Vec<(usize, &VehicleModel)> = self
            .models
            .iter()
            .enumerate()
            .filter(|(_, m)| m.class == class)
            .collect();
        let u = rng::unit(traffic_seed, Purpose::VehicleModel, &[id_hash, 0]);
        let k = pick(of_class.iter().map(|(_, m)| m.share), u)?;
        let (index, model) = of_class[k];
        let u = rng::unit(traffic_seed, Purpose::VehicleModel, &[id_hash, 1]);
        let p = pick(model.paints.iter().map(|p| p.share), u)?;
        Some((u16::try_from(index).ok()?, &model.paints[p]))
    }
}

/// The index whose cumulative share first passes `u` (the last on
/// rounding); `None` without entries.
fn pick(shares: impl Iterator<Item = f64>, u: f64) -> Option<usize> {
    let mut acc = 0.0;
    let mut last = None;
    for (k, s) in shares.enumerate() {
        acc += s;
        last = Some(k);
        if u < acc {
            return Some(k);
        }
    }
    last
}

fn check_shares(shares: impl Iterator<Item = f64>) -> Result<(), String> {
    let mut total = 0.0;
    let mut n = 0;
    for s in shares {
        if !(s.is_finite() && s > 0.0) {
            return Err(format!("a share must be positive, not {s}"));
        }
        total += s;
        n += 1;
    }
    if n == 0 {
        return Err("no entry".into());
    }
    if (total - 1.0).abs() > SHARE_TOLERANCE {
        return Err(format!("the shares sum to {total}, not 1"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_catalogue_reads_and_draws_by_its_shares() {
        let c = Catalogue::shipped();
        let cars: Vec<&VehicleModel> = c
            .models
            .iter()
            .filter(|m| m.class == ObjectClass::Car)
            .collect();
        assert!(cars.len() >= 5, "{}", cars.len());
        let n = 20_000;
        let mut counts = vec![0usize; c.models.len()];
        for k in 0..n {
            let (m, paint) = c.draw(5, &format!("veh{k}"), ObjectClass::Car).unwrap();
            counts[usize::from(m)] += 1;
            assert!(c.models[usize::from(m)].paints.contains(paint));
        }
        for (m, model) in c.models.iter().enumerate() {
            if model.class == ObjectClass::Car {
                let share = counts[m] as f64 / f64::from(n);
                assert!(
                    (share - model.share).abs() < 0.015,
                    "{}: {share}",
                    model.name
                );
            } else {
                assert_eq!(counts[m], 0);
            }
        }
        // A vehicle keeps its look; the traffic seed takes part.
        assert_eq!(
            c.draw(5, "veh1", ObjectClass::Car),
            c.draw(5, "veh1", ObjectClass::Car)
        );
        assert!((0..40).any(|k| {
            let id = format!("v{k}");
            c.draw(5, &id, ObjectClass::Car) != c.draw(6, &id, ObjectClass::Car)
        }));
        assert!(c.draw(5, "p0", ObjectClass::Pedestrian).is_none());
    }

    #[test]
    fn a_bad_catalogue_says_what_is_wrong() {
        let palette =
            "[palettes]\ncar = [{ name = \"white\", rgb = [255, 255, 255], share = 1.0 }]\n";
        let model = |share: f64, length: f64, palette: &str| {
            format!(
                "[[models]]\nname = \"m\"\nclass = \"car\"\nlength_m = {length}\nwidth_m = 1.8\n\
                 height_m = 1.5\nshare = {share}\npalette = \"{palette}\"\nsource = \"s\"\n"
            )
        };
        let ok = format!("{palette}{}", model(1.0, 4.5, "car"));
        assert_eq!(Catalogue::parse(&ok).unwrap().models.len(), 1);
        let cases = [
            (format!("{palette}{}", model(0.5, 4.5, "car")), "sum to 0.5"),
            (format!("{palette}{}", model(1.0, -1.0, "car")), "length"),
            (
                format!("{palette}{}", model(1.0, 4.5, "van")),
                "no palette 'van'",
            ),
            (palette.to_owned(), "missing field"),
        ];
        for (text, says) in cases {
            let e = Catalogue::parse(&text).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
    }
}
