//! The network's weights as bytes (burn's burnpack format, what a
//! `<method>.bpk` file holds) and back, refusing weights that do not fit
//! the architecture or hold a value that is not finite. Files are the
//! caller's business.

use burn::module::Param;
use burn::prelude::*;

use super::init::Init;
use crate::matching::deep::arch::Architecture;
use crate::matching::deep::ours::OursNet;

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

/// The weights of [`module_bytes`] loaded into `empty` (a network of the
/// right shape); weights that do not fit or hold a value that is not
/// finite are refused.
pub(crate) fn load_module<M: Module>(empty: M, bytes: &[u8]) -> Result<M, String> {
    let record =
        burn::store::ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))
            .map_err(|e| format!("{e:?}"))?;
    let module = empty
        .try_load_record(record)
        .map_err(|e| format!("{e:?}"))?;
    let mut finite = AllFinite(true);
    module.visit(&mut finite);
    if !finite.0 {
        return Err("the weights hold a value that is not a finite number".into());
    }
    Ok(module)
}

/// A network of architecture `arch` on `device` with the weights of
/// [`to_bytes`]; weights whose scalar parameters are not finite are
/// refused.
pub(crate) fn from_bytes(
    arch: &Architecture,
    bytes: &[u8],
    device: &Device,
) -> Result<OursNet, String> {
    load_module(OursNet::new(arch, Init::Zeros, device), bytes)
}

/// Whether every float parameter of a module is finite.
struct AllFinite(bool);

impl burn::module::ModuleVisitor for AllFinite {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.0 {
            let data = param.val().into_data();
            self.0 = data.iter::<f32>().all(f32::is_finite);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_that_are_not_finite_do_not_load() {
        let arch = Architecture::default();
        let device = crate::matching::deep::backend::device();
        let fine = OursNet::new(&arch, Init::Seeded(3), &device);
        assert!(from_bytes(&arch, &to_bytes(&fine).unwrap(), &device).is_ok());
        let broken = OursNet::new(&arch, Init::Seeded(3), &device).with_gates(f32::NAN);
        let e = from_bytes(&arch, &to_bytes(&broken).unwrap(), &device).unwrap_err();
        assert!(e.contains("not a finite number"), "{e}");
    }

    #[test]
    fn weights_survive_bytes_and_bad_bytes_are_refused() {
        let device = crate::matching::deep::backend::device();
        let arch = Architecture::default();
        let net = OursNet::new(&arch, Init::Seeded(9), &device);
        let bytes = to_bytes(&net).unwrap();
        let back = from_bytes(&arch, &bytes, &device).unwrap();
        assert_eq!(to_bytes(&back).unwrap(), bytes);
        assert!(from_bytes(&arch, b"junk", &device).is_err());
        // Weights of another architecture do not fit.
        let other = Architecture {
            consensus: false,
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
