//! A pickle reader that only builds values: the opcodes of protocols 2 to
//! 5 that make numbers, text, tuples, lists and dicts, and the few globals
//! a PyTorch Geometric `Data` saved with `torch.save` names ([`Global`]).
//! Every other global (`os.system`, `builtins.eval`, any class) is refused
//! by name before anything is called: a file from elsewhere cannot make
//! this reader run code, because this reader never runs any.

use std::collections::HashMap;

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
    F32,
    F64,
    I64,
    I32,
    I16,
    U8,
    Bool,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F64 | DType::I64 => 8,
            DType::F32 | DType::I32 => 4,
            DType::I16 => 2,
            DType::U8 | DType::Bool => 1,
        }
    }
}

impl Global {
    /// The global `module.name`, if it is one this reader builds.
    fn named(module: &str, name: &str) -> Option<Global> {
        Some(match (module, name) {
            ("torch_geometric.data.data", "Data") => Global::PygData,
            ("torch_geometric.data.data", "DataEdgeAttr" | "DataTensorAttr") => {
                Global::PygAttrClass
            }
            ("torch_geometric.data.storage", "GlobalStorage") => Global::PygStorage,
            ("torch._utils", "_rebuild_tensor_v2") => Global::RebuildTensor,
            ("collections", "OrderedDict") => Global::OrderedDict,
            ("torch", storage) => Global::Storage(match storage {
                "FloatStorage" => DType::F32,
                "DoubleStorage" => DType::F64,
                "LongStorage" => DType::I64,
                "IntStorage" => DType::I32,
                "ShortStorage" => DType::I16,
                "ByteStorage" => DType::U8,
                "BoolStorage" => DType::Bool,
                _ => return None,
            }),
            _ => return None,
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
    #[error("it uses pickle opcode 0x{0:02x}, which coid does not read")]
    Opcode(u8),
    #[error("it ends before its STOP")]
    Truncated,
    #[error("it is malformed at byte {at}: {why}")]
    Malformed { at: usize, why: String },
}

/// Reads a pickle into a [`Value`], building nothing but values.
pub fn read(bytes: &[u8]) -> Result<Value, PickleError> {
    Machine {
        bytes,
        at: 0,
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    }
    .run()
}

struct Machine<'a> {
    bytes: &'a [u8],
    at: usize,
    stack: Vec<Value>,
    marks: Vec<usize>,
    memo: HashMap<u32, Value>,
}

impl Machine<'_> {
    fn malformed(&self, why: impl Into<String>) -> PickleError {
        PickleError::Malformed {
            at: self.at,
            why: why.into(),
        }
    }

    fn take(&mut self, n: usize) -> Result<&[u8], PickleError> {
        let end = self.at.checked_add(n).ok_or(PickleError::Truncated)?;
        let s = self.bytes.get(self.at..end).ok_or(PickleError::Truncated)?;
        self.at = end;
        Ok(s)
    }

    fn uint(&mut self, n: usize) -> Result<u64, PickleError> {
        let s = self.take(n)?;
        Ok(s.iter().rev().fold(0u64, |v, &b| (v << 8) | u64::from(b)))
    }

    fn len(&mut self, n: usize) -> Result<usize, PickleError> {
        let v = self.uint(n)?;
        usize::try_from(v).map_err(|_| self.malformed("a length out of range"))
    }

    fn text(&mut self, n: usize) -> Result<String, PickleError> {
        let s = self.take(n)?.to_vec();
        String::from_utf8(s).map_err(|_| self.malformed("text that is not UTF-8"))
    }

    fn line(&mut self) -> Result<String, PickleError> {
        let rest = self.bytes.get(self.at..).ok_or(PickleError::Truncated)?;
        let n = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or(PickleError::Truncated)?;
        let s = self.text(n)?;
        self.at += 1;
        Ok(s)
    }

    fn pop(&mut self) -> Result<Value, PickleError> {
        self.stack
            .pop()
            .ok_or_else(|| self.malformed("an empty stack"))
    }

    fn pop_mark(&mut self) -> Result<Vec<Value>, PickleError> {
        let mark = self.marks.pop().ok_or_else(|| self.malformed("no mark"))?;
        if mark > self.stack.len() {
            return Err(self.malformed("a mark above the stack"));
        }
        Ok(self.stack.split_off(mark))
    }

    fn top(&mut self) -> Result<&mut Value, PickleError> {
        let at = self.at;
        self.stack.last_mut().ok_or(PickleError::Malformed {
            at,
            why: "an empty stack".into(),
        })
    }

    fn put(&mut self, key: u32) -> Result<(), PickleError> {
        let v = self.top()?.clone();
        self.memo.insert(key, v);
        Ok(())
    }

    fn get(&mut self, key: u32) -> Result<(), PickleError> {
        let v = self
            .memo
            .get(&key)
            .cloned()
            .ok_or_else(|| self.malformed(format!("memo {key} was never put")))?;
        self.stack.push(v);
        Ok(())
    }

    fn global(&mut self, module: &str, name: &str) -> Result<(), PickleError> {
        let g = Global::named(module, name)
            .ok_or_else(|| PickleError::Refused(format!("{module}.{name}")))?;
        self.stack.push(Value::Global(g));
        Ok(())
    }

    fn run(mut self) -> Result<Value, PickleError> {
        loop {
            let op = self.take(1)?[0];
            if op == b'.' {
                return self.pop();
            }
            self.step(op)?;
        }
    }

    #[allow(clippy::too_many_lines)] // one arm per opcode
    fn step(&mut self, op: u8) -> Result<(), PickleError> {
        match op {
            0x80 => {
                self.take(1)?;
            }
            0x95 => {
                self.take(8)?;
            }
            b'(' => self.marks.push(self.stack.len()),
            b'0' => {
                self.pop()?;
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let v = self.top()?.clone();
                self.stack.push(v);
            }
            b'N' => self.stack.push(Value::None),
            0x88 => self.stack.push(Value::Bool(true)),
            0x89 => self.stack.push(Value::Bool(false)),
            b'J' => {
                let v = self.uint(4)? as u32 as i32;
                self.stack.push(Value::Int(i64::from(v)));
            }
            b'K' => {
                let v = self.uint(1)?;
                self.stack.push(Value::Int(v as i64));
            }
            b'M' => {
                let v = self.uint(2)?;
                self.stack.push(Value::Int(v as i64));
            }
            0x8a => {
                let n = self.len(1)?;
                if n > 8 {
                    return Err(self.malformed("an integer wider than 64 bits"));
                }
                let s = self.take(n)?;
                let mut v: i64 = 0;
                for (k, &b) in s.iter().enumerate() {
                    v |= i64::from(b) << (8 * k);
                }
                if n > 0 && n < 8 && s[n - 1] & 0x80 != 0 {
                    v -= 1i64 << (8 * n);
                }
                self.stack.push(Value::Int(v));
            }
            b'G' => {
                let s = self.take(8)?;
                let v = f64::from_be_bytes(s.try_into().expect("8 bytes"));
                self.stack.push(Value::Float(v));
            }
            b'X' => {
                let n = self.len(4)?;
                let s = self.text(n)?;
                self.stack.push(Value::Text(s));
            }
            0x8c => {
                let n = self.len(1)?;
                let s = self.text(n)?;
                self.stack.push(Value::Text(s));
            }
            0x8d => {
                let n = self.len(8)?;
                let s = self.text(n)?;
                self.stack.push(Value::Text(s));
            }
            b'C' | b'B' | 0x8e => {
                let n = match op {
                    b'C' => self.len(1)?,
                    b'B' => self.len(4)?,
                    _ => self.len(8)?,
                };
                let s = self.take(n)?.to_vec();
                self.stack.push(Value::Bytes(s));
            }
            b')' => self.stack.push(Value::Tuple(Vec::new())),
            b't' => {
                let items = self.pop_mark()?;
                self.stack.push(Value::Tuple(items));
            }
            0x85..=0x87 => {
                let n = usize::from(op - 0x84);
                if self.stack.len() < n {
                    return Err(self.malformed("a tuple longer than the stack"));
                }
                let items = self.stack.split_off(self.stack.len() - n);
                self.stack.push(Value::Tuple(items));
            }
            b']' => self.stack.push(Value::List(Vec::new())),
            b'l' => {
                let items = self.pop_mark()?;
                self.stack.push(Value::List(items));
            }
            b'a' => {
                let v = self.pop()?;
                self.append(vec![v])?;
            }
            b'e' => {
                let items = self.pop_mark()?;
                self.append(items)?;
            }
            b'}' => self.stack.push(Value::Dict(Vec::new())),
            b'd' => {
                let items = self.pop_mark()?;
                let d = self.pairs(items)?;
                self.stack.push(Value::Dict(d));
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                self.set_items(vec![(k, v)])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                let d = self.pairs(items)?;
                self.set_items(d)?;
            }
            b'c' => {
                let module = self.line()?;
                let name = self.line()?;
                self.global(&module, &name)?;
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (Value::Text(module), Value::Text(name)) = (module, name) else {
                    return Err(self.malformed("STACK_GLOBAL without two texts"));
                };
                self.global(&module, &name)?;
            }
            b'q' => {
                let k = self.uint(1)? as u32;
                self.put(k)?;
            }
            b'r' => {
                let k = self.uint(4)? as u32;
                self.put(k)?;
            }
            0x94 => {
                let k = self.memo.len() as u32;
                self.put(k)?;
            }
            b'h' => {
                let k = self.uint(1)? as u32;
                self.get(k)?;
            }
            b'j' => {
                let k = self.uint(4)? as u32;
                self.get(k)?;
            }
            b'Q' => {
                let pid = self.pop()?;
                let v = self.storage(pid)?;
                self.stack.push(v);
            }
            b'R' => {
                let args = self.pop()?;
                let callable = self.pop()?;
                let v = self.reduce(callable, args)?;
                self.stack.push(v);
            }
            0x81 => {
                let _args = self.pop()?;
                let class = self.pop()?;
                let v = self.instance(class)?;
                self.stack.push(v);
            }
            b'b' => {
                let state = self.pop()?;
                match self.top()? {
                    Value::Object { state: s, .. } => *s = Some(Box::new(state)),
                    Value::Dict(_) if state == Value::None => {}
                    _ => return Err(self.malformed("BUILD on a value that is not an object")),
                }
            }
            other => return Err(PickleError::Opcode(other)),
        }
        Ok(())
    }

    fn append(&mut self, items: Vec<Value>) -> Result<(), PickleError> {
        match self.top()? {
            Value::List(l) => {
                l.extend(items);
                Ok(())
            }
            _ => Err(self.malformed("APPEND to a value that is not a list")),
        }
    }

    fn pairs(&self, items: Vec<Value>) -> Result<Vec<(Value, Value)>, PickleError> {
        if !items.len().is_multiple_of(2) {
            return Err(self.malformed("a dict with an odd number of items"));
        }
        let mut it = items.into_iter();
        let mut out = Vec::new();
        while let (Some(k), Some(v)) = (it.next(), it.next()) {
            out.push((k, v));
        }
        Ok(out)
    }

    fn set_items(&mut self, items: Vec<(Value, Value)>) -> Result<(), PickleError> {
        match self.top()? {
            Value::Dict(d) => {
                for (k, v) in items {
                    match d.iter_mut().find(|(old, _)| *old == k) {
                        Some(slot) => slot.1 = v,
                        None => d.push((k, v)),
                    }
                }
                Ok(())
            }
            _ => Err(self.malformed("SETITEM on a value that is not a dict")),
        }
    }

    fn instance(&self, class: Value) -> Result<Value, PickleError> {
        match class {
            Value::Global(g @ (Global::PygData | Global::PygStorage | Global::PygAttrClass)) => {
                Ok(Value::Object {
                    class: g,
                    state: None,
                })
            }
            Value::Global(Global::OrderedDict) => Ok(Value::Dict(Vec::new())),
            _ => Err(self.malformed("NEWOBJ of something that is not a class coid builds")),
        }
    }

    /// A persistent id: `('storage', <Type>Storage, key, location, numel)`.
    fn storage(&self, pid: Value) -> Result<Value, PickleError> {
        let Value::Tuple(items) = pid else {
            return Err(self.malformed("a persistent id that is not a tuple"));
        };
        match items.as_slice() {
            [
                Value::Text(kind),
                Value::Global(Global::Storage(dtype)),
                Value::Text(key),
                Value::Text(_location),
                Value::Int(numel),
            ] if kind == "storage" && *numel >= 0 => Ok(Value::Storage {
                dtype: *dtype,
                key: key.clone(),
                numel: *numel as usize,
            }),
            _ => Err(self.malformed("a persistent id that is not a tensor storage")),
        }
    }

    fn reduce(&self, callable: Value, args: Value) -> Result<Value, PickleError> {
        let Value::Tuple(args) = args else {
            return Err(self.malformed("REDUCE arguments that are not a tuple"));
        };
        match callable {
            Value::Global(Global::OrderedDict) if args.is_empty() => Ok(Value::Dict(Vec::new())),
            Value::Global(Global::RebuildTensor) => self.tensor(&args),
            Value::Global(g @ (Global::PygData | Global::PygStorage)) => Ok(Value::Object {
                class: g,
                state: None,
            }),
            _ => Err(self.malformed("REDUCE of something coid does not build")),
        }
    }

    /// `_rebuild_tensor_v2(storage, offset, size, stride, requires_grad,
    /// hooks[, metadata])`.
    fn tensor(&self, args: &[Value]) -> Result<Value, PickleError> {
        let ints = |v: &Value| -> Option<Vec<usize>> {
            let Value::Tuple(items) = v else { return None };
            items
                .iter()
                .map(|x| match x {
                    Value::Int(i) if *i >= 0 => Some(*i as usize),
                    _ => None,
                })
                .collect()
        };
        match args {
            [
                Value::Storage { dtype, key, numel },
                Value::Int(offset),
                size,
                stride,
                ..,
            ] if *offset >= 0 => {
                let (Some(shape), Some(stride)) = (ints(size), ints(stride)) else {
                    return Err(self.malformed("a tensor's size or stride is not integers"));
                };
                if shape.len() != stride.len() {
                    return Err(self.malformed("a tensor's size and stride differ in length"));
                }
                Ok(Value::Tensor(TensorView {
                    dtype: *dtype,
                    key: key.clone(),
                    numel: *numel,
                    offset: *offset as usize,
                    shape,
                    stride,
                }))
            }
            _ => Err(self.malformed("a tensor rebuilt from something that is not a storage")),
        }
    }
}
