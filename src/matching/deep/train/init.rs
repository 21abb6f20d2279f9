//! Where a network's modules get their values: the parameters of
//! [`crate::matching::deep::params`] (a weights file's, or a seeded start
//! drawn from one named stream per parameter, never burn's own
//! generator) as burn's parameters, each with an id derived from its
//! stream name ([`named_param`]), so that the same seed gives the same
//! weights and the same bytes, and inference reads what training holds.

use burn::module::{Param, ParamId};
use burn::nn::Linear;
use burn::prelude::*;

use crate::matching::deep::params::{ParamSpec, Params};
use crate::rng;

/// Where a new network's weights come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Init {
    /// Uniform draws from the stream `(seed, WeightInit, hash(parameter
    /// name))`: the same seed gives the same weights, whatever else was
    /// drawn before.
    Seeded(u64),
}

impl Init {
    /// The parameters of `specs` as this start gives them.
    pub(crate) fn params(self, specs: &[ParamSpec]) -> Params {
        let Init::Seeded(seed) = self;
        Params::seeded(specs, seed)
    }
}

/// The values of a network's parameters, to build its modules from.
pub(crate) struct Source<'a> {
    pub(crate) params: &'a Params,
    pub(crate) specs: &'a [ParamSpec],
    pub(crate) device: &'a Device,
}

impl Source<'_> {
    /// The parameter `key` as a burn parameter of rank `D`.
    ///
    /// # Panics
    /// When `key` is not in the network's spec or has another rank (a
    /// module built wrong, not a weights file: those are checked against
    /// the spec when read).
    pub(crate) fn param<const D: usize>(&self, key: &str) -> Param<Tensor<D>> {
        let spec = self
            .specs
            .iter()
            .find(|s| s.key == key)
            .unwrap_or_else(|| panic!("no parameter {key} in the network's spec"));
        let (shape, values) = self.params.get(key);
        let shape: [usize; D] = shape
            .try_into()
            .unwrap_or_else(|_| panic!("{key}: rank {} where {D} is read", shape.len()));
        let t = Tensor::from_data(TensorData::new(values.to_vec(), shape), self.device);
        named_param(&spec.stream, t)
    }

    /// The linear layer `name` (`<name>.weight`, `<name>.bias`).
    pub(crate) fn linear(&self, name: &str) -> Linear {
        Linear {
            weight: self.param(&format!("{name}.weight")),
            bias: Some(self.param(&format!("{name}.bias"))),
        }
    }
}

/// A trainable parameter whose id is derived from its name (burn draws
/// ids at random, which would make saved weights differ from run to run).
pub(crate) fn named_param<const D: usize>(name: &str, value: Tensor<D>) -> Param<Tensor<D>> {
    // Through `Parameter`: a tensor without autodiff is left as it is.
    let value = <Tensor<D> as burn::module::Parameter>::set_require_grad(value, true);
    Param::initialized(ParamId::from(rng::hash_str(name)), value)
}
