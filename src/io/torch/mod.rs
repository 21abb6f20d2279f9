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
    /// A tensor's values in row-major order, with its shape and the
    /// type it was stored as.
    Tensor {
        shape: Vec<usize>,
        values: Vec<f64>,
        dtype: DType,
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
/// slice). What the file can make coid build is bounded by its size: the
/// pickle by [`pickle::object_budget`], the tensors' values by the
/// archive's bytes (each view checked against its storage, and each
/// storage against its entry, before anything is allocated).
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
    let file_len = file.metadata().map_err(|e| io(e.to_string()))?.len();
    let mut zip = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| io(format!("not a torch.save archive ({e})")))?;
    let pickle_name = root_pickle(&zip).map_err(&io)?;
    let prefix = pickle_name.trim_end_matches("data.pkl").to_owned();
    let mut read_entry = |name: &str, need: Option<(u64, &str)>| -> Result<Vec<u8>, PtError> {
        let f = zip
            .by_name(name)
            .map_err(|e| io(format!("no {name} in the archive ({e})")))?;
        let limit = match need {
            Some((bytes, what)) if bytes > f.size() => {
                return Err(content(format!(
                    "storage {what} should hold {bytes} bytes, its archive entry holds {}",
                    f.size()
                )));
            }
            Some((bytes, _)) => bytes,
            None => f.size().min(file_len),
        };
        let mut buf = Vec::new();
        f.take(limit)
            .read_to_end(&mut buf)
            .map_err(|e| io(e.to_string()))?;
        Ok(buf)
    };
    let root =
        pickle::read(&read_entry(&pickle_name, None)?).map_err(|source| PtError::Pickle {
            path: shown.clone(),
            source,
        })?;
    let mut storages: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    // Every value read becomes an f64: at most the archive's bytes of them.
    let mut left = usize::try_from(file_len).unwrap_or(usize::MAX).max(1 << 16);
    let mut tensor = |v: &TensorView| -> Result<Vec<f64>, PtError> {
        let count = view_count(v, left).map_err(&content)?;
        if !storages.contains_key(&v.key) {
            let bytes = v
                .numel
                .checked_mul(v.dtype.size())
                .ok_or_else(|| content(format!("storage {} declares {} values", v.key, v.numel)))?;
            let bytes = read_entry(
                &format!("{prefix}data/{}", v.key),
                Some((bytes as u64, &v.key)),
            )?;
            storages.insert(v.key.clone(), bytes);
        }
        left -= count;
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

/// The folders of `dir` whose names are numbers (a PyG source's pair
/// folders), by number.
pub fn numbered_folders(dir: &Path) -> Result<Vec<u64>, String> {
    let listing = |e: std::io::Error| format!("cannot list {}: {e}", dir.display());
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(listing)? {
        let entry = entry.map_err(listing)?;
        if let Some(k) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<u64>().ok())
        {
            out.push(k);
        }
    }
    out.sort_unstable();
    Ok(out)
}

/// The archive's one pickle, `<archive>/data.pkl`.
fn root_pickle<R: std::io::Read + std::io::Seek>(
    zip: &zip::ZipArchive<R>,
) -> Result<String, String> {
    let roots: Vec<String> = zip
        .file_names()
        .filter_map(Result::ok)
        .filter(|n| n.ends_with("/data.pkl") && n.matches('/').count() == 1)
        .map(|n| n.into_owned())
        .collect();
    match roots.as_slice() {
        [one] => Ok(one.clone()),
        [] => Err("no data.pkl in the archive (not a torch.save file)".into()),
        [a, b, ..] => Err(format!(
            "the archive holds {} pickles ({a}, {b}, ...), torch.save writes one",
            roots.len()
        )),
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
                    dtype: t.dtype,
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
/// (each field's boundaries along its first dimension, from 0, never
/// decreasing; text fields are lists and are not cut).
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
        let b: Vec<usize> = b
            .iter()
            .map(|&x| (x >= 0.0 && x.fract() == 0.0 && x < 2f64.powi(52)).then_some(x as usize))
            .collect::<Option<_>>()
            .ok_or_else(|| format!("the slices of '{name}' are not indices >= 0"))?;
        if b.first().is_some_and(|&f| f != 0) || b.windows(2).any(|w| w[1] < w[0]) {
            return Err(format!(
                "the slices of '{name}' do not rise from 0 (each graph's rows follow the last's)"
            ));
        }
        bounds.insert(name.clone(), b);
    }
    let n = bounds.values().map(|b| b.len().saturating_sub(1)).max();
    let n = n.ok_or("its slices name no field")?;
    let mut out = vec![Graph::new(); n];
    for (name, field) in whole {
        let Field::Tensor {
            shape,
            values,
            dtype,
        } = field
        else {
            continue;
        };
        let Some(b) = bounds.get(name) else { continue };
        let row: usize = shape.iter().skip(1).product();
        for (g, w) in b.windows(2).enumerate() {
            let part = w[0]
                .checked_mul(row)
                .zip(w[1].checked_mul(row))
                .and_then(|(lo, hi)| values.get(lo..hi))
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
                    dtype: *dtype,
                },
            );
        }
    }
    Ok(Ok(out))
}

/// How many values a tensor view holds, checked before anything is read:
/// its size (no overflow, at most `left`, what the archive may still
/// give), and every element it reaches inside its storage.
fn view_count(v: &TensorView, left: usize) -> Result<usize, String> {
    let count = v
        .shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= left)
        .ok_or_else(|| {
            format!(
                "a tensor of size {:?} holds more values than the file has bytes",
                v.shape
            )
        })?;
    if count == 0 {
        return Ok(0);
    }
    let last = v
        .shape
        .iter()
        .zip(&v.stride)
        .try_fold(v.offset, |at, (&n, &s)| {
            at.checked_add((n - 1).checked_mul(s)?)
        });
    match last {
        Some(last) if last < v.numel => Ok(count),
        _ => Err(format!(
            "a tensor of size {:?}, stride {:?} from element {} reaches outside its storage of \
             {} values",
            v.shape, v.stride, v.offset, v.numel
        )),
    }
}

/// A tensor view's values in row-major order, read from its storage's
/// bytes (the view checked by [`view_count`]).
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
    let two = || [b[0], b[1]];
    let four = || [b[0], b[1], b[2], b[3]];
    match dtype {
        DType::F64 => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")),
        DType::F32 => f64::from(f32::from_le_bytes(four())),
        DType::F16 => f64::from(half::f16::from_le_bytes(two())),
        DType::BF16 => f64::from(half::bf16::from_le_bytes(two())),
        DType::I64 => i64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as f64,
        DType::I32 => f64::from(i32::from_le_bytes(four())),
        DType::I16 => f64::from(i16::from_le_bytes(two())),
        DType::I8 => f64::from(b[0] as i8),
        DType::U8 | DType::Bool => f64::from(b[0]),
    }
}
