//! A network's parameters as plain numbers, by name: what a `.bpk` file
//! holds (burn's burnpack container, read with the `burn-pack` format
//! crate, no tensors), or what a fresh network starts from (one seeded
//! stream per parameter). Inference reads its layers from here, and
//! training builds its modules from the same values, so that a network
//! and its untrained start are one declaration ([`ParamSpec`]) away from
//! both.

use std::collections::BTreeMap;

use rand::Rng;

use crate::rng::{self, Purpose};

use super::kernels::lanes::PlainLinear;

/// How a parameter starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Start {
    /// Uniform in `(-bound, bound)` from its own stream (zeros when the
    /// bound is 0).
    Uniform(f64),
    /// Every value this one.
    Constant(f32),
}

/// One parameter of a network: its name in a weights file, the name of
/// its random stream (and of its id in training), its shape and start.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ParamSpec {
    pub(crate) key: String,
    pub(crate) stream: String,
    pub(crate) shape: Vec<usize>,
    pub(crate) start: Start,
}

impl ParamSpec {
    /// Values in the spec's shape.
    fn len(&self) -> usize {
        self.shape.iter().product()
    }
}

/// The parameters of a spline convolution `d_in -> d_out` with `cells`
/// kernel cells (5 knots over edge length, or 25 cells over 2-D
/// offsets): the cells' weights side by side `[in, cells out]`, the root
/// `[in, out]` (both uniform in `+-1/sqrt(in)`: the fan-in of one cell)
/// and the bias (zeros). `prefix`: the stream names' prefix.
pub(crate) fn spline_conv(
    name: &str,
    prefix: &str,
    [d_in, d_out]: [usize; 2],
    cells: usize,
) -> Vec<ParamSpec> {
    let b = 1.0 / (d_in as f64).sqrt();
    vec![
        spec(
            name,
            prefix,
            "weight",
            vec![d_in, cells * d_out],
            Start::Uniform(b),
        ),
        spec(name, prefix, "root", vec![d_in, d_out], Start::Uniform(b)),
        spec(name, prefix, "bias", vec![d_out], Start::Constant(0.0)),
    ]
}

/// The parameters of a linear layer `d_in -> d_out` (weight `[in, out]`
/// and bias, uniform in `+-1/sqrt(in)` as burn's default).
pub(crate) fn linear(name: &str, prefix: &str, [d_in, d_out]: [usize; 2]) -> Vec<ParamSpec> {
    let b = 1.0 / (d_in as f64).sqrt();
    vec![
        spec(name, prefix, "weight", vec![d_in, d_out], Start::Uniform(b)),
        spec(name, prefix, "bias", vec![d_out], Start::Uniform(b)),
    ]
}

/// A scalar parameter `[1]` starting at `v`.
pub(crate) fn scalar(name: &str, prefix: &str, v: f32) -> ParamSpec {
    ParamSpec {
        key: name.to_owned(),
        stream: format!("{prefix}{name}"),
        shape: vec![1],
        start: Start::Constant(v),
    }
}

fn spec(layer: &str, prefix: &str, part: &str, shape: Vec<usize>, start: Start) -> ParamSpec {
    ParamSpec {
        key: format!("{layer}.{part}"),
        stream: format!("{prefix}{layer}.{part}"),
        shape,
        start,
    }
}

/// A network's parameters by name, each row-major with its shape.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Params {
    values: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Params {
    /// The parameters of `specs` as a fresh network has them: each
    /// uniform one from the stream `(seed, WeightInit, hash(stream
    /// name))`, so that the same seed gives the same weights whatever
    /// else was drawn.
    pub(crate) fn seeded(specs: &[ParamSpec], seed: u64) -> Self {
        let values = specs
            .iter()
            .map(|s| {
                let n = s.len();
                let v = match s.start {
                    Start::Constant(v) => vec![v; n],
                    Start::Uniform(b) if b > 0.0 => {
                        let mut r =
                            rng::stream(seed, Purpose::WeightInit, &[rng::hash_str(&s.stream)]);
                        (0..n).map(|_| r.random_range(-b..b) as f32).collect()
                    }
                    Start::Uniform(_) => vec![0.0; n],
                };
                (s.key.clone(), (s.shape.clone(), v))
            })
            .collect();
        Self { values }
    }

    /// The parameters a `.bpk` file holds, checked against `specs`: every
    /// parameter there with its shape, nothing else, f32 values that are
    /// finite.
    pub(crate) fn from_bytes(bytes: &[u8], specs: &[ParamSpec]) -> Result<Self, String> {
        let reader =
            burn_pack::Reader::from_bytes(burn_pack::Bytes::from_bytes_vec(bytes.to_vec()))
                .map_err(|e| format!("not a weights file ({e:?})"))?;
        let mut values = BTreeMap::new();
        for t in reader.into_tensors().map_err(|e| format!("{e:?}"))? {
            if t.dtype != burn_pack::DType::F32 {
                return Err(format!("{} is {:?}, not f32", t.name, t.dtype));
            }
            let shape = t.shape.to_vec();
            let bytes = t.to_bytes().map_err(|e| format!("{e:?}"))?;
            let v: Vec<f32> = bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            if v.len() != shape.iter().product::<usize>() {
                return Err(format!(
                    "{} holds {} values for shape {shape:?}",
                    t.name,
                    v.len()
                ));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err("the weights hold a value that is not a finite number".into());
            }
            values.insert(t.name, (shape, v));
        }
        let params = Self { values };
        params.check(specs)?;
        Ok(params)
    }

    /// Parameters given by name (`(name, shape, values)`), checked as
    /// [`Self::from_bytes`] checks a file's.
    pub(crate) fn from_named(
        named: Vec<(String, Vec<usize>, Vec<f32>)>,
        specs: &[ParamSpec],
    ) -> Result<Self, String> {
        let mut values = BTreeMap::new();
        for (name, shape, v) in named {
            if v.len() != shape.iter().product::<usize>() {
                return Err(format!(
                    "{name} holds {} values for shape {shape:?}",
                    v.len()
                ));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format!("{name} holds a value that is not a finite number"));
            }
            values.insert(name, (shape, v));
        }
        let params = Self { values };
        params.check(specs)?;
        Ok(params)
    }

    /// Whether these are the parameters of `specs`, by name and shape.
    fn check(&self, specs: &[ParamSpec]) -> Result<(), String> {
        for s in specs {
            match self.values.get(&s.key) {
                None => return Err(format!("the weights have no {}", s.key)),
                Some((shape, _)) if *shape != s.shape => {
                    return Err(format!(
                        "the weights' {} has shape {shape:?}, the network's {:?}",
                        s.key, s.shape
                    ));
                }
                Some(_) => {}
            }
        }
        if let Some(extra) = self
            .values
            .keys()
            .find(|k| !specs.iter().any(|s| s.key == **k))
        {
            return Err(format!(
                "the weights hold {extra}, which the network does not have"
            ));
        }
        Ok(())
    }

    /// The values of `key` (row-major) with its shape.
    ///
    /// # Panics
    /// When there is no such parameter: the network asked for one its
    /// own spec does not declare (a bug, not a weights file: those are
    /// checked against the spec).
    pub(crate) fn get(&self, key: &str) -> (&[usize], &[f32]) {
        let (shape, v) = self
            .values
            .get(key)
            .unwrap_or_else(|| panic!("no parameter {key} in the network's spec"));
        (shape, v)
    }

    /// `key` set to `values` (tests: a network as training leaves it).
    #[cfg(test)]
    pub(crate) fn set(&mut self, key: &str, values: &[f32]) {
        let (shape, v) = self.values.get_mut(key).expect("a parameter of the spec");
        assert_eq!(v.len(), values.len(), "{key}: {shape:?}");
        v.copy_from_slice(values);
    }

    /// Every parameter by name (in name order): shape and values.
    pub(crate) fn iter(&self) -> impl Iterator<Item = (&str, &[usize], &[f32])> {
        self.values
            .iter()
            .map(|(k, (shape, v))| (k.as_str(), shape.as_slice(), v.as_slice()))
    }

    /// The values of `key`.
    pub(crate) fn values(&self, key: &str) -> &[f32] {
        self.get(key).1
    }

    /// The scalar `key`.
    pub(crate) fn scalar(&self, key: &str) -> f32 {
        self.values(key)[0]
    }

    /// The linear layer `name` as plain numbers.
    pub(crate) fn linear(&self, name: &str) -> PlainLinear {
        let (shape, weight) = self.get(&format!("{name}.weight"));
        PlainLinear {
            d_in: shape[0],
            d_out: shape[1],
            weight: weight.to_vec(),
            bias: self.values(&format!("{name}.bias")).to_vec(),
        }
    }
}
