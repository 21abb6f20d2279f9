//! The one place burn's backend is chosen, and the one way tensor values
//! are read back: the networks' modules, training and the tensor
//! reference of inference all go through here.

use burn::prelude::*;

/// A failed read of a tensor's values (a backend that cannot give f32).
#[cfg(test)]
pub(crate) type TensorRead = String;

/// The device every tensor of the deep networks lives on (burn's CPU
/// backend).
pub(crate) fn device() -> Device {
    Device::flex()
}

/// A tensor's values as f32, row-major; an error if the backend cannot
/// give them.
#[cfg(test)]
pub(crate) fn values<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>, TensorRead> {
    t.try_into_vec_as::<f32>()
        .map_err(|e| format!("a tensor's values could not be read as f32: {e:?}"))
}
