//! PyTorch Geometric graphs read from `.pt` files without torch and
//! without running anything from them. A `torch.save` file is a zip: a
//! pickle (`<archive>/data.pkl`) that describes the objects, and each
//! tensor's storage as raw little-endian bytes (`<archive>/data/<key>`).
//! The pickle is read by [`pickle`], which builds only values, tensors
//! and PyG's `Data` and refuses every other global; tensors are then read
//! from their storages honouring offset and strides (a saved tensor may be
//! a transposed view).

mod pickle;
#[cfg(test)]
pub(crate) mod tests;

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

pub use pickle::{DType, PickleError};
use pickle::{Global, TensorView, Value};

/// One field of a graph.
#[derive(Clone, Debug, PartialEq)]
pub enum Field {
    /// A tensor's values in row-major order, with its shape.
    Tensor {
        shape: Vec<usize>,
        values: Vec<f64>,
    },
    Text(String),
    Number(f64),
    /// Anything else a `Data` may hold (a list, `None`, ...): not read.
    Other,
}

/// A PyG `Data`: its fields by name.
pub type Graph = BTreeMap<String, Field>;

/// Why a `.pt` file was not read.
#[derive(Debug, thiserror::Error)]
pub enum PtError {
    #[error("cannot read {path}: {why}")]
    Io { path: String, why: String },
    #[error("{path} is not read: {source}")]
    Pickle { path: String, source: PickleError },
    #[error("{path}: {why}")]
    Content { path: String, why: String },
}

/// The graphs a `.pt` file holds: a PyG `Data`, or an `InMemoryDataset`'s
/// `(data, slices)` (one graph when `slices` is `None`, else one per
/// slice).
pub fn read_graphs(path: &Path) -> Result<Vec<Graph>, PtError> {
    let shown = path.display().to_string();
    let io = |why: String| PtError::Io {
        path: shown.clone(),
        why,
    };
    let content = |why: String| PtError::Content {
        path: shown.clone(),
        why,
    };
    let file = std::fs::File::open(path).map_err(|e| io(e.to_string()))?;
    let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| io(format!("not a torch.save archive ({e})")))?;
    let pickle_name = zip
        .file_names()
        .filter_map(Result::ok)
        .find(|n| n.ends_with("/data.pkl") && n.matches('/').count() == 1)
        .map(|n| n.into_owned())
        .ok_or_else(|| io("no data.pkl in the archive (not a torch.save file)".into()))?;
    let prefix = pickle_name.trim_end_matches("data.pkl").to_owned();
    let mut read_entry = |name: &str| -> Result<Vec<u8>, PtError> {
        let mut f = zip
            .by_name(name)
            .map_err(|e| io(format!("no {name} in the archive ({e})")))?;
        let mut buf = Vec::new();
        f.read_to_end(&mut buf).map_err(|e| io(e.to_string()))?;
        Ok(buf)
    };
    let root = pickle::read(&read_entry(&pickle_name)?).map_err(|source| PtError::Pickle {
        path: shown.clone(),
        source,
    })?;
    let mut storages: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    let mut tensor = |v: &TensorView| -> Result<Vec<f64>, PtError> {
        if !storages.contains_key(&v.key) {
            let bytes = read_entry(&format!("{prefix}data/{}", v.key))?;
            storages.insert(v.key.clone(), bytes);
        }
        values(v, &storages[&v.key]).map_err(&content)
    };
    let (data, slices) = match &root {
        Value::Tuple(items) if items.len() == 2 => (&items[0], Some(&items[1])),
        other => (other, None),
    };
    let whole = graph(data, &mut tensor).map_err(&content)??;
    match slices {
        None | Some(Value::None) => Ok(vec![whole]),
        Some(s) => split(&whole, s, &mut tensor).map_err(content)?,
    }
}

/// The fields of a `Data` (PyG 2: its `_store`'s `_mapping`; PyG 1: its
/// attributes).
fn graph(
    data: &Value,
    tensor: &mut impl FnMut(&TensorView) -> Result<Vec<f64>, PtError>,
) -> Result<Result<Graph, PtError>, String> {
    let Value::Object {
        class: Global::PygData,
        state: Some(state),
    } = data
    else {
        return Err("it holds no PyTorch Geometric Data".into());
    };
    let mapping = match state.get("_store") {
        Some(Value::Object {
            state: Some(store), ..
        }) => store
            .get("_mapping")
            .ok_or("its Data's storage has no _mapping")?,
        _ => state,
    };
    let Value::Dict(items) = mapping else {
        return Err("its Data's fields are not a dict".into());
    };
    let mut out = Graph::new();
    for (k, v) in items {
        let Value::Text(name) = k else { continue };
        if name.starts_with('_') {
            continue;
        }
        let field = match v {
            Value::Tensor(t) => match tensor(t) {
                Ok(values) => Field::Tensor {
                    shape: t.shape.clone(),
                    values,
                },
                Err(e) => return Ok(Err(e)),
            },
            Value::Text(s) => Field::Text(s.clone()),
            Value::Int(i) => Field::Number(*i as f64),
            Value::Float(x) => Field::Number(*x),
            _ => Field::Other,
        };
        out.insert(name.clone(), field);
    }
    Ok(Ok(out))
}

/// An `InMemoryDataset`'s collated `data` cut into its graphs by `slices`
/// (each field's boundaries along its first dimension; text fields are
/// lists and are not cut).
fn split(
    whole: &Graph,
    slices: &Value,
    tensor: &mut impl FnMut(&TensorView) -> Result<Vec<f64>, PtError>,
) -> Result<Result<Vec<Graph>, PtError>, String> {
    let Value::Dict(items) = slices else {
        return Err("its slices are not a dict".into());
    };
    let mut bounds: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (k, v) in items {
        let (Value::Text(name), Value::Tensor(t)) = (k, v) else {
            continue;
        };
        let b = match tensor(t) {
            Ok(b) => b,
            Err(e) => return Ok(Err(e)),
        };
        bounds.insert(name.clone(), b.iter().map(|&x| x as usize).collect());
    }
    let n = bounds.values().map(|b| b.len().saturating_sub(1)).max();
    let n = n.ok_or("its slices name no field")?;
    let mut out = vec![Graph::new(); n];
    for (name, field) in whole {
        let Field::Tensor { shape, values } = field else {
            continue;
        };
        let Some(b) = bounds.get(name) else { continue };
        let row: usize = shape.iter().skip(1).product();
        for (g, w) in b.windows(2).enumerate() {
            let (lo, hi) = (w[0] * row, w[1] * row);
            let part = values
                .get(lo..hi)
                .ok_or_else(|| format!("slices of '{name}' lie outside it"))?;
            let mut s = shape.clone();
            if let Some(first) = s.first_mut() {
                *first = w[1] - w[0];
            }
            out[g].insert(
                name.clone(),
                Field::Tensor {
                    shape: s,
                    values: part.to_vec(),
                },
            );
        }
    }
    Ok(Ok(out))
}

/// A tensor view's values in row-major order, read from its storage's
/// bytes; refused when the view reaches outside the storage.
fn values(v: &TensorView, bytes: &[u8]) -> Result<Vec<f64>, String> {
    let size = v.dtype.size();
    let have = bytes.len() / size;
    if have < v.numel {
        return Err(format!(
            "storage {} holds {have} values, its header says {}",
            v.key, v.numel
        ));
    }
    let count: usize = v.shape.iter().product();
    let mut out = Vec::with_capacity(count);
    if count == 0 {
        return Ok(out);
    }
    let last = v.offset
        + v.shape
            .iter()
            .zip(&v.stride)
            .map(|(&n, &s)| (n - 1) * s)
            .sum::<usize>();
    if last >= v.numel {
        return Err(format!(
            "a tensor's view reaches element {last} of a storage of {}",
            v.numel
        ));
    }
    let mut index = vec![0usize; v.shape.len()];
    for _ in 0..count {
        let at = v.offset
            + index
                .iter()
                .zip(&v.stride)
                .map(|(i, s)| i * s)
                .sum::<usize>();
        out.push(element(v.dtype, &bytes[at * size..(at + 1) * size]));
        for d in (0..index.len()).rev() {
            index[d] += 1;
            if index[d] < v.shape[d] {
                break;
            }
            index[d] = 0;
        }
    }
    Ok(out)
}

fn element(dtype: DType, b: &[u8]) -> f64 {
    let a = |n: usize| -> [u8; 8] {
        let mut x = [0u8; 8];
        x[..n].copy_from_slice(&b[..n]);
        x
    };
    match dtype {
        DType::F32 => f64::from(f32::from_le_bytes(a(4)[..4].try_into().expect("4"))),
        DType::F64 => f64::from_le_bytes(a(8)),
        DType::I64 => i64::from_le_bytes(a(8)) as f64,
        DType::I32 => f64::from(i32::from_le_bytes(a(4)[..4].try_into().expect("4"))),
        DType::I16 => f64::from(i16::from_le_bytes(a(2)[..2].try_into().expect("2"))),
        DType::U8 | DType::Bool => f64::from(b[0]),
    }
}
