//! The one place burn's backend is chosen, and the one way tensor values
//! are read back: the networks' modules, training and the tensor
//! reference of inference all go through here.

use burn::nn::Linear;
use burn::prelude::*;

use super::kernels::lanes::PlainLinear;
use super::mc::TensorRead;

/// The device every tensor of the deep networks lives on (burn's CPU
/// backend).
pub(crate) fn device() -> Device {
    Device::flex()
}

/// A tensor's values as f32, row-major; an error if the backend cannot
/// give them.
pub(crate) fn values<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>, TensorRead> {
    t.try_into_vec_as::<f32>()
        .map_err(|e| format!("a tensor's values could not be read as f32: {e:?}"))
}

/// A linear layer's parameters as plain numbers (inference).
pub(crate) fn linear(l: &Linear) -> Result<PlainLinear, TensorRead> {
    let [d_in, d_out] = l.weight.val().dims();
    Ok(PlainLinear {
        d_in,
        d_out,
        weight: values(l.weight.val())?,
        bias: match &l.bias {
            Some(b) => values(b.val())?,
            None => vec![0.0; d_out],
        },
    })
}
