//! Where a new network's weights come from: one named random stream per
//! parameter ([`Init`]), never burn's own generator, and parameter ids
//! derived from the names ([`named_param`]), so that the same seed gives
//! the same weights and the same bytes.

use burn::module::{Param, ParamId};
use burn::nn::Linear;
use burn::prelude::*;
use rand::Rng;

use crate::rng::{self, Purpose};

/// Where a new network's weights come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Init {
    /// Uniform draws from the stream `(seed, WeightInit, hash(parameter
    /// name))`: the same seed gives the same weights, whatever else was
    /// drawn before.
    Seeded(u64),
    /// Zeros: a skeleton about to receive trained weights.
    Zeros,
}

impl Init {
    /// A tensor of `shape` drawn uniformly from `(-bound, bound)`.
    fn uniform<const D: usize>(
        self,
        name: &str,
        shape: [usize; D],
        bound: f64,
        device: &Device,
    ) -> Tensor<D> {
        match self {
            Init::Seeded(seed) if bound > 0.0 => {
                let mut s = rng::stream(seed, Purpose::WeightInit, &[rng::hash_str(name)]);
                let n = shape.iter().product();
                let v: Vec<f32> = (0..n)
                    .map(|_| s.random_range(-bound..bound) as f32)
                    .collect();
                Tensor::from_data(TensorData::new(v, shape), device)
            }
            _ => Tensor::zeros(shape, device),
        }
    }

    /// The parameter `name`, drawn uniformly from `(-bound, bound)`.
    pub(crate) fn param<const D: usize>(
        self,
        name: &str,
        shape: [usize; D],
        bound: f64,
        device: &Device,
    ) -> Param<Tensor<D>> {
        named_param(name, self.uniform(name, shape, bound, device))
    }

    /// A linear layer `[d_in] -> [d_out]` initialised like burn's default
    /// (weight and bias uniform in `+-1/sqrt(d_in)`).
    pub(crate) fn linear(self, name: &str, d_in: usize, d_out: usize, device: &Device) -> Linear {
        let b = 1.0 / (d_in as f64).sqrt();
        Linear {
            weight: self.param(&format!("{name}.weight"), [d_in, d_out], b, device),
            bias: Some(self.param(&format!("{name}.bias"), [d_out], b, device)),
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
