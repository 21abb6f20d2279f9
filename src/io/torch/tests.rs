use std::path::Path;

use super::*;

#[path = "../../../tests/integration/pt_writer.rs"]
pub(crate) mod pt_writer;

use pt_writer::{Pickle, PtField, PtTensor, archive, pyg_data};

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// A graph in PyG's layout comes back field by field: tensors with their
/// shapes and values (a transposed view read through its strides, an int
/// tensor as integers), text as text.
#[test]
fn a_pyg_data_file_is_read_field_by_field() {
    let dir = tempfile::tempdir().unwrap();
    let x: Vec<f64> = (0..12).map(|k| f64::from(k) * 0.25).collect();
    let pos: Vec<f64> = (0..6).map(|k| f64::from(k) - 2.5).collect();
    let bytes = pyg_data(&[
        (
            "x",
            PtField::Tensor(PtTensor::float(x.clone(), &[3, 4]).transposed()),
        ),
        (
            "pos",
            PtField::Tensor(PtTensor::float(pos.clone(), &[3, 2])),
        ),
        (
            "y",
            PtField::Tensor(PtTensor::int(vec![7.0, -1.0, 9.0], &[3])),
        ),
        ("name", PtField::Text("scene/001".into())),
    ]);
    let graphs = read_graphs(&write(dir.path(), "g.pt", &bytes)).unwrap();
    assert_eq!(graphs.len(), 1);
    let g = &graphs[0];
    assert_eq!(
        g["x"],
        Field::Tensor {
            shape: vec![3, 4],
            values: x,
            dtype: DType::F32,
        }
    );
    assert_eq!(
        g["pos"],
        Field::Tensor {
            shape: vec![3, 2],
            values: pos,
            dtype: DType::F32,
        }
    );
    assert_eq!(
        g["y"],
        Field::Tensor {
            shape: vec![3],
            values: vec![7.0, -1.0, 9.0],
            dtype: DType::I32,
        }
    );
    assert_eq!(g["name"], Field::Text("scene/001".into()));
}

/// A pickle that would run code when torch loads it (`os.system`, or
/// `builtins.eval` named through STACK_GLOBAL) is refused by the name of
/// the global, before anything is built.
#[test]
fn a_pickle_that_would_run_code_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Pickle::default();
    p.op(0x80)
        .op(2)
        .global("os", "system")
        .text("touch pwned")
        .op(0x85);
    p.op(b'R').op(b'.');
    let path = write(dir.path(), "evil.pt", &archive(&p.0, &[]));
    let e = read_graphs(&path).unwrap_err().to_string();
    assert!(e.contains("names the global os.system"), "{e}");
    let mut p = Pickle::default();
    p.op(0x80).op(4).text("builtins").text("eval").op(0x93);
    p.text("__import__('os').system('touch pwned')")
        .op(0x85)
        .op(b'R')
        .op(b'.');
    let path = write(dir.path(), "evil2.pt", &archive(&p.0, &[]));
    let e = read_graphs(&path).unwrap_err().to_string();
    assert!(e.contains("builtins.eval"), "{e}");
    assert!(!dir.path().join("pwned").exists());
    // An opcode coid does not read (INST builds any class) is refused too.
    let path = write(
        dir.path(),
        "inst.pt",
        &archive(b"\x80\x02(ios\nsystem\n.", &[]),
    );
    let e = read_graphs(&path).unwrap_err().to_string();
    assert!(e.contains("opcode 0x69"), "{e}");
}

/// A file that is not a torch.save archive, or whose tensor reaches
/// outside its storage, is refused with the reason.
#[test]
fn a_broken_pt_file_is_refused_with_its_reason() {
    let dir = tempfile::tempdir().unwrap();
    let e = read_graphs(&write(dir.path(), "a.pt", b"not a zip")).unwrap_err();
    assert!(e.to_string().contains("not a torch.save archive"), "{e}");
    let mut bytes = pyg_data(&[("x", PtField::Tensor(PtTensor::float(vec![1.0; 6], &[3, 2])))]);
    // Cut the storage short: the zip is rewritten with 8 bytes of it.
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(&mut bytes)).unwrap();
    let mut pickle = Vec::new();
    std::io::Read::read_to_end(&mut zip.by_name("archive/data.pkl").unwrap(), &mut pickle).unwrap();
    let short = archive(&pickle, &[vec![0u8; 8]]);
    let e = read_graphs(&write(dir.path(), "b.pt", &short)).unwrap_err();
    assert!(
        e.to_string()
            .contains("storage 0 should hold 24 bytes, its archive entry holds 8"),
        "{e}"
    );
}

/// Half, bfloat16 and int8 tensors are read as the values they hold; a
/// storage type coid does not read is named.
#[test]
fn half_bfloat16_and_int8_tensors_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let v = vec![0.5, -2.0, 1024.0];
    let bytes = pyg_data(&[
        (
            "h",
            PtField::Tensor(PtTensor::float(v.clone(), &[3]).stored_as("HalfStorage")),
        ),
        (
            "b",
            PtField::Tensor(PtTensor::float(v.clone(), &[3]).stored_as("BFloat16Storage")),
        ),
        (
            "c",
            PtField::Tensor(PtTensor::float(vec![-3.0, 7.0, 0.0], &[3]).stored_as("CharStorage")),
        ),
    ]);
    let g = &read_graphs(&write(dir.path(), "g.pt", &bytes)).unwrap()[0];
    for (name, dtype) in [("h", DType::F16), ("b", DType::BF16)] {
        assert_eq!(
            g[name],
            Field::Tensor {
                shape: vec![3],
                values: v.clone(),
                dtype
            }
        );
    }
    assert!(
        matches!(&g["c"], Field::Tensor { values, dtype: DType::I8, .. } if *values == [-3.0, 7.0, 0.0])
    );
    let odd = pyg_data(&[(
        "z",
        PtField::Tensor(PtTensor::float(vec![1.0], &[1]).stored_as("ComplexFloatStorage")),
    )]);
    let e = read_graphs(&write(dir.path(), "z.pt", &odd))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a tensor of torch.ComplexFloatStorage, a type coid does not read"),
        "{e}"
    );
}

/// A memo reference is shared, not copied: a list put in the memo before
/// its items are appended holds them when it is got again (as in Python);
/// a list inside itself is a cycle, not followed.
#[test]
fn memo_references_share_one_object() {
    // [] PUT 0, MARK 1 2 APPENDS, POP, GET 0: the list [1, 2].
    let p = [
        0x80, 2, b']', b'q', 0, b'(', b'K', 1, b'K', 2, b'e', b'0', b'h', 0, b'.',
    ];
    assert_eq!(
        super::pickle::read(&p).unwrap(),
        Value::List(vec![Value::Int(1), Value::Int(2)])
    );
    // [] PUT 0, GET 0, APPEND: a list that holds itself.
    let p = [0x80, 2, b']', b'q', 0, b'h', 0, b'a', b'.'];
    assert_eq!(
        super::pickle::read(&p),
        Ok(Value::List(vec![Value::Ancestor]))
    );
}

/// A negative stride or size is named as what it is.
#[test]
fn a_negative_stride_is_called_negative() {
    let mut p = pt_writer::Pickle::default();
    p.op(0x80)
        .op(2)
        .global("torch._utils", "_rebuild_tensor_v2")
        .op(b'(');
    p.op(b'(').text("storage").global("torch", "FloatStorage");
    p.text("0").text("cpu").int(4).op(b't').op(b'Q').int(0);
    p.op(b'(').int(2).op(b't');
    // A stride of -1 (BININT holds it).
    p.op(b'(').op(b'J');
    p.0.extend((-1i32).to_le_bytes());
    p.op(b't').op(0x89).op(b')').op(b't').op(b'R').op(b'.');
    let e = super::pickle::read(&p.0).unwrap_err().to_string();
    assert!(e.contains("a tensor's stride holds -1 (negative)"), "{e}");
}
