//! Writes `.pt` files in the layout `torch.save` gives a PyTorch Geometric
//! `Data` (PyG 2: `Data` -> `_store` `GlobalStorage` -> `_mapping`), with
//! tensors as `_rebuild_tensor_v2` views of raw storages, so that tests
//! can make small datasets without torch. Used by the unit tests of
//! `io::torch` and by the integration tests.

use std::io::Write;

/// A tensor to write: its values in row-major order with their shape, in
/// the storage type `storage` (`FloatStorage`: f32, `IntStorage`: i32,
/// `BoolStorage`, `HalfStorage`, `BFloat16Storage`, `CharStorage`: i8);
/// `transposed` stores a 2-D tensor column-major and describes it as a
/// transposed view, as torch does for `.t()`; `declared` claims another
/// size than the values have (a file that lies).
pub struct PtTensor {
    pub values: Vec<f64>,
    pub shape: Vec<usize>,
    pub storage: &'static str,
    pub transposed: bool,
    pub declared: Option<Vec<usize>>,
}

impl PtTensor {
    pub fn float(values: Vec<f64>, shape: &[usize]) -> Self {
        PtTensor {
            values,
            shape: shape.to_vec(),
            storage: "FloatStorage",
            transposed: false,
            declared: None,
        }
    }

    pub fn int(values: Vec<f64>, shape: &[usize]) -> Self {
        PtTensor::float(values, shape).stored_as("IntStorage")
    }

    pub fn stored_as(mut self, storage: &'static str) -> Self {
        self.storage = storage;
        self
    }

    pub fn transposed(mut self) -> Self {
        self.transposed = true;
        self
    }

    /// Claims size `shape` (with contiguous strides) over the same storage.
    #[allow(dead_code, reason = "used by the integration tests only")]
    pub fn declared(mut self, shape: &[usize]) -> Self {
        self.declared = Some(shape.to_vec());
        self
    }
}

/// A field of a `Data`.
pub enum PtField {
    Tensor(PtTensor),
    Text(String),
    /// Pickle opcodes that push the field's value.
    #[allow(dead_code, reason = "used by the integration tests only")]
    Pickle(Vec<u8>),
}

/// A pickle assembled opcode by opcode.
#[derive(Default)]
pub struct Pickle(pub Vec<u8>);

impl Pickle {
    pub fn op(&mut self, op: u8) -> &mut Self {
        self.0.push(op);
        self
    }

    pub fn global(&mut self, module: &str, name: &str) -> &mut Self {
        self.0.push(b'c');
        self.0.extend(format!("{module}\n{name}\n").bytes());
        self
    }

    pub fn text(&mut self, s: &str) -> &mut Self {
        self.0.push(b'X');
        self.0.extend((s.len() as u32).to_le_bytes());
        self.0.extend(s.bytes());
        self
    }

    pub fn int(&mut self, v: usize) -> &mut Self {
        if v > i32::MAX as usize {
            // LONG1 of 8 bytes: sizes no i32 holds.
            self.0.extend([0x8a, 8]);
            self.0.extend((v as u64).to_le_bytes());
            return self;
        }
        self.0.push(b'J');
        self.0.extend((v as i32).to_le_bytes());
        self
    }

    fn ints(&mut self, v: &[usize]) -> &mut Self {
        self.op(b'(');
        for &x in v {
            self.int(x);
        }
        self.op(b't')
    }

    /// `_rebuild_tensor_v2(('storage', <T>Storage, key, 'cpu', numel),
    /// 0, shape, stride, False, OrderedDict())`.
    fn tensor(&mut self, t: &PtTensor, key: usize) -> &mut Self {
        let storage = t.storage;
        let shape = t.declared.as_ref().unwrap_or(&t.shape);
        let stride: Vec<usize> = if t.transposed && shape.len() == 2 {
            vec![1, shape[0]]
        } else {
            let mut s = vec![1usize; shape.len()];
            for d in (0..shape.len().saturating_sub(1)).rev() {
                s[d] = s[d + 1].saturating_mul(shape[d + 1]);
            }
            s
        };
        self.global("torch._utils", "_rebuild_tensor_v2").op(b'(');
        self.op(b'(').text("storage").global("torch", storage);
        self.text(&key.to_string()).text("cpu").int(t.values.len());
        self.op(b't').op(b'Q').int(0).ints(shape).ints(&stride);
        self.op(0x89)
            .global("collections", "OrderedDict")
            .op(b')')
            .op(b'R');
        self.op(b't').op(b'R')
    }
}

/// The raw little-endian storage of a tensor.
fn storage(t: &PtTensor) -> Vec<u8> {
    let order: Vec<f64> = if t.transposed && t.shape.len() == 2 {
        let (r, c) = (t.shape[0], t.shape[1]);
        (0..c)
            .flat_map(|j| (0..r).map(move |i| (i, j)))
            .map(|(i, j)| t.values[i * c + j])
            .collect()
    } else {
        t.values.clone()
    };
    let mut out = Vec::new();
    for v in order {
        match t.storage {
            "IntStorage" => out.extend((v as i32).to_le_bytes()),
            "BoolStorage" => out.push(u8::from(v != 0.0)),
            "CharStorage" => out.push(v as i8 as u8),
            "HalfStorage" => out.extend(half_bits(v).to_le_bytes()),
            "BFloat16Storage" => out.extend((((v as f32).to_bits() >> 16) as u16).to_le_bytes()),
            _ => out.extend((v as f32).to_le_bytes()),
        }
    }
    out
}

/// The IEEE half of `v` (normal numbers and zero, rounded down: enough for
/// test values).
fn half_bits(v: f64) -> u16 {
    let b = (v as f32).to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32 - 127 + 15;
    if v == 0.0 || exp <= 0 {
        return sign;
    }
    sign | ((exp as u16) << 10) | ((b >> 13) & 0x3ff) as u16
}

/// A `torch.save` archive of `pickle` and `storages` (named `0`, `1`, ...).
pub fn archive(pickle: &[u8], storages: &[Vec<u8>]) -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut put = |name: &str, bytes: &[u8]| {
        zip.start_file(format!("archive/{name}"), opts).unwrap();
        zip.write_all(bytes).unwrap();
    };
    put("data.pkl", pickle);
    for (k, s) in storages.iter().enumerate() {
        put(&format!("data/{k}"), s);
    }
    put("version", b"3\n");
    zip.finish().unwrap().into_inner()
}

/// The bytes of a `.pt` file holding `(Data(**fields), None)`, as PyG's
/// `InMemoryDataset` saves one graph.
pub fn pyg_data(fields: &[(&str, PtField)]) -> Vec<u8> {
    let mut p = Pickle::default();
    let mut storages = Vec::new();
    p.op(0x80).op(2);
    p.global("torch_geometric.data.data", "Data")
        .op(b')')
        .op(0x81);
    p.op(b'q').op(1);
    p.op(b'}').op(b'(').text("_edge_attr_cls");
    p.global("torch_geometric.data.data", "DataEdgeAttr")
        .text("_store");
    p.global("torch_geometric.data.storage", "GlobalStorage")
        .op(b')')
        .op(0x81);
    p.op(b'}').op(b'(').text("_mapping").op(b'}').op(b'(');
    for (name, field) in fields {
        p.text(name);
        match field {
            PtField::Tensor(t) => {
                p.tensor(t, storages.len());
                storages.push(storage(t));
            }
            PtField::Text(s) => {
                p.text(s);
            }
            PtField::Pickle(ops) => {
                p.0.extend(ops);
            }
        }
    }
    p.op(b'u').text("_parent").op(b'h').op(1).op(b'u').op(b'b');
    p.op(b'u').op(b'b').op(b'N').op(0x86).op(b'.');
    archive(&p.0, &storages)
}
