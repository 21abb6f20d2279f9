//! What a pickle may build: the globals coid knows, storages' element
//! types, tensor views, values, and why a pickle is refused.

use super::MAX_DEPTH;

/// A global a pickle may name: what `torch.save` of a PyG `Data` uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Global {
    /// `torch_geometric.data.data.Data` (and its `DataEdgeAttr`,
    /// `DataTensorAttr`, which it names as attribute classes).
    PygData,
    PygAttrClass,
    /// `torch_geometric.data.storage.GlobalStorage`: the `Data`'s fields.
    PygStorage,
    /// `torch._utils._rebuild_tensor_v2`: a tensor from a storage.
    RebuildTensor,
    /// `torch.<Type>Storage`: a storage's element type.
    Storage(DType),
    /// `collections.OrderedDict`.
    OrderedDict,
}

/// A storage's element type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    F64,
    F32,
    F16,
    BF16,
    I64,
    I32,
    I16,
    I8,
    U8,
    Bool,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F64 | DType::I64 => 8,
            DType::F32 | DType::I32 => 4,
            DType::F16 | DType::BF16 | DType::I16 => 2,
            DType::I8 | DType::U8 | DType::Bool => 1,
        }
    }

    /// Whether its values are floating point.
    pub fn is_float(self) -> bool {
        matches!(self, DType::F64 | DType::F32 | DType::F16 | DType::BF16)
    }

    /// torch's name of it.
    pub fn name(self) -> &'static str {
        match self {
            DType::F64 => "float64",
            DType::F32 => "float32",
            DType::F16 => "float16",
            DType::BF16 => "bfloat16",
            DType::I64 => "int64",
            DType::I32 => "int32",
            DType::I16 => "int16",
            DType::I8 => "int8",
            DType::U8 => "uint8",
            DType::Bool => "bool",
        }
    }

    /// The element type of `torch.<name>`, a legacy storage class.
    fn of_storage(name: &str) -> Option<DType> {
        Some(match name {
            "DoubleStorage" => DType::F64,
            "FloatStorage" => DType::F32,
            "HalfStorage" => DType::F16,
            "BFloat16Storage" => DType::BF16,
            "LongStorage" => DType::I64,
            "IntStorage" => DType::I32,
            "ShortStorage" => DType::I16,
            "CharStorage" => DType::I8,
            "ByteStorage" => DType::U8,
            "BoolStorage" => DType::Bool,
            _ => return None,
        })
    }
}

impl Global {
    /// The global `module.name`, if it is one this reader builds.
    pub(super) fn named(module: &str, name: &str) -> Result<Global, PickleError> {
        Ok(match (module, name) {
            ("torch_geometric.data.data", "Data") => Global::PygData,
            ("torch_geometric.data.data", "DataEdgeAttr" | "DataTensorAttr") => {
                Global::PygAttrClass
            }
            ("torch_geometric.data.storage", "GlobalStorage") => Global::PygStorage,
            ("torch._utils", "_rebuild_tensor_v2") => Global::RebuildTensor,
            ("collections", "OrderedDict") => Global::OrderedDict,
            ("torch", storage) if storage.ends_with("Storage") => Global::Storage(
                DType::of_storage(storage)
                    .ok_or_else(|| PickleError::Storage(format!("{module}.{name}")))?,
            ),
            _ => return Err(PickleError::Refused(format!("{module}.{name}"))),
        })
    }
}

/// A tensor as a pickle describes it: a view of a storage.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorView {
    pub dtype: DType,
    /// The storage's name in the archive (`data/<key>`).
    pub key: String,
    /// The storage's element count.
    pub numel: usize,
    /// The view: first element, shape and strides, in elements.
    pub offset: usize,
    pub shape: Vec<usize>,
    pub stride: Vec<usize>,
}

/// A value a pickle builds.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Text(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    Dict(Vec<(Value, Value)>),
    Global(Global),
    /// An instance of an allowed class, with the state `BUILD` gave it.
    Object {
        class: Global,
        state: Option<Box<Value>>,
    },
    /// A storage, as a persistent id names it.
    Storage {
        dtype: DType,
        key: String,
        numel: usize,
    },
    Tensor(TensorView),
    /// A reference to an object that holds it (a cycle, as a PyG
    /// storage's `_parent`, the `Data` it belongs to): not followed.
    Ancestor,
}

impl Value {
    /// The value under text key `key` of a dict.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Dict(items) => items
                .iter()
                .find(|(k, _)| matches!(k, Value::Text(t) if t == key))
                .map(|(_, v)| v),
            _ => None,
        }
    }
}

/// Why a pickle was not read.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PickleError {
    #[error(
        "it names the global {0}, which coid does not build (only tensors, PyG's Data and plain values)"
    )]
    Refused(String),
    #[error(
        "it holds a tensor of {0}, a type coid does not read (float64, float32, float16, \
         bfloat16, int64, int32, int16, int8, uint8 and bool)"
    )]
    Storage(String),
    #[error("it uses pickle opcode 0x{0:02x}, which coid does not read")]
    Opcode(u8),
    #[error("it ends before its STOP")]
    Truncated,
    #[error("it is malformed at byte {at}: {why}")]
    Malformed { at: usize, why: String },
    #[error(
        "it builds more than {limit} objects from a {bytes}-byte pickle (an object it refers \
         to again counts each time; coid reads no pickle that expands like this)"
    )]
    Expands { limit: usize, bytes: usize },
    #[error("it nests values more than {MAX_DEPTH} deep")]
    TooDeep,
}
