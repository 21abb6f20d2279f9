//! The networks' weights as bytes (burn's burnpack format, what a
//! `<method>.bpk` file holds) and back into modules, refusing weights that
//! do not fit the architecture or hold a value that is not finite. Files
//! are the caller's business.

use burn::prelude::*;

use super::ours_net::OursNet;
#[cfg(test)]
use super::published_net::PublishedNet;
#[cfg(test)]
use crate::matching::deep::arch::{Architecture, PublishedConfig};
#[cfg(test)]
use crate::matching::deep::params::Params;
#[cfg(test)]
use crate::matching::deep::{ours, published};

/// The network's weights as bytes (burn's burnpack format, what a
/// `<method>.bpk` file holds).
pub(crate) fn to_bytes(net: &OursNet) -> Result<Vec<u8>, String> {
    module_bytes(net)
}

/// Any network's weights as bytes (burnpack).
pub(crate) fn module_bytes<M: Module + Clone>(module: &M) -> Result<Vec<u8>, String> {
    let bytes = module
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| format!("{e:?}"))?;
    Ok(bytes.to_vec())
}

/// The weights file (`.bpk` bytes) of `method`'s published network,
/// reading appearance vectors `appearance_width` wide, with the parameters
/// `named` (`(name, shape, values)`, as
/// [`crate::matching::deep::PublishedForward::parameters`] gives them):
/// weights trained elsewhere (`tools/dgmc_reference/train.py`) for coid
/// to run.
pub fn published_weights(
    method: crate::matching::Method,
    appearance_width: crate::sensor::AppearanceWidth,
    named: Vec<(String, Vec<usize>, Vec<f32>)>,
) -> Result<Vec<u8>, String> {
    use crate::matching::deep::arch::Backbone;
    let Some(Backbone::Published(cfg)) = method
        .backbone()
        .map(|b| b.with_appearance(appearance_width))
    else {
        return Err(format!(
            "{} is not a network on the paper's inputs",
            method.as_str()
        ));
    };
    let specs = crate::matching::deep::published::spec(&cfg);
    let params = crate::matching::deep::params::Params::from_named(named, &specs)?;
    let device = super::backend::device();
    module_bytes(&super::published_net::PublishedNet::from_params(
        &cfg, &params, &specs, &device,
    ))
}

/// `ours`'s network of `arch` on `device` with the weights of
/// [`to_bytes`]; weights that do not fit the architecture or hold a value
/// that is not finite are refused ([`Params::from_bytes`]).
#[cfg(test)]
pub(crate) fn from_bytes(
    arch: &Architecture,
    bytes: &[u8],
    device: &Device,
) -> Result<OursNet, String> {
    let specs = ours::spec(arch);
    let p = Params::from_bytes(bytes, &specs)?;
    Ok(OursNet::from_params(arch, &p, &specs, device))
}

/// A published network of `cfg` on `device` with the weights of
/// [`module_bytes`], refused as [`from_bytes`] refuses them.
#[cfg(test)]
pub(crate) fn published_from_bytes(
    cfg: &PublishedConfig,
    bytes: &[u8],
    device: &Device,
) -> Result<PublishedNet, String> {
    let specs = published::spec(cfg);
    let p = Params::from_bytes(bytes, &specs)?;
    Ok(PublishedNet::from_params(cfg, &p, &specs, device))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::train::init::Init;

    #[test]
    fn weights_that_are_not_finite_do_not_load() {
        let arch = Architecture::default();
        let device = crate::matching::deep::train::backend::device();
        let fine = OursNet::new(&arch, Init::Seeded(3), &device);
        assert!(from_bytes(&arch, &to_bytes(&fine).unwrap(), &device).is_ok());
        let broken = OursNet::new(&arch, Init::Seeded(3), &device).with_gates(f32::NAN);
        let e = from_bytes(&arch, &to_bytes(&broken).unwrap(), &device).unwrap_err();
        assert!(e.contains("not a finite number"), "{e}");
    }

    #[test]
    fn weights_survive_bytes_and_bad_bytes_are_refused() {
        let device = crate::matching::deep::train::backend::device();
        let arch = Architecture::default();
        let net = OursNet::new(&arch, Init::Seeded(9), &device);
        let bytes = to_bytes(&net).unwrap();
        let back = from_bytes(&arch, &bytes, &device).unwrap();
        assert_eq!(to_bytes(&back).unwrap(), bytes);
        assert!(from_bytes(&arch, b"junk", &device).is_err());
        // Weights of another architecture do not fit.
        let other = Architecture {
            consensus_steps: 0,
            ..arch
        };
        let other_bytes = to_bytes(&OursNet::new(&other, Init::Seeded(9), &device)).unwrap();
        assert!(from_bytes(&arch, &other_bytes, &device).is_err());
        // A gate that is not a number is refused.
        let broken = OursNet::new(&arch, Init::Seeded(9), &device).with_gate_values(f32::NAN, 0.0);
        let e = from_bytes(&arch, &to_bytes(&broken).unwrap(), &device)
            .err()
            .unwrap();
        assert!(e.contains("finite"), "{e}");
    }
}
