//! `.pt` files from elsewhere, tried as a hostile user would: crafted
//! files that would exhaust memory, overflow the stack or abort; values
//! that are not numbers, wrong types and malformed names that would pass
//! and change the numbers (datasets' own files: `hostile_datasets`).
//! Each test is named after the defect it keeps fixed and goes through
//! the real binary.

use std::process::Output;

use crate::dataset::{convert, convert_split, view, write_pairs};
use crate::pt_writer::{PtField, PtTensor, archive, pyg_data};
use crate::util::*;

/// `coid args` with its address space capped at 4 GB (`ulimit -v
/// 4000000`): every crafted file must be refused within it.
fn coid_capped(fx: &Fixture, args: &[&str]) -> Output {
    std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 4000000; exec \"$0\" \"$@\"")
        .arg(BIN)
        .args(args)
        .current_dir(fx.dir.path())
        .env("COID_HOME", fx.path(".coid-home"))
        .env("COID_VENV", venv())
        .output()
        .unwrap()
}

/// Converts the fixture's pairs with pair 11's second view replaced by
/// `bytes`, memory capped; the refusal must name the file and say `why`
/// in one line, and nothing be written.
fn refused_as_pair_11(bytes: &[u8], why: &str) {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    std::fs::write(fx.path("src/proc_t/11/data.pt"), bytes).unwrap();
    let (src, out) = (fx.path("src"), fx.path("ds"));
    let o = coid_capped(
        &fx,
        &[
            "convert",
            "pyg",
            src.to_str().unwrap(),
            "-q",
            "-o",
            out.to_str().unwrap(),
            "--splits",
            "test=10..12",
        ],
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert_eq!(e.trim_end().lines().count(), 1, "one line: {e}");
    assert!(e.contains("proc_t/11/data.pt") && e.contains(why), "{e}");
    assert!(!out.exists());
}

/// Opcodes that push one list: 30 levels, each the level below ten
/// times (a memo reference repeated: 10^30 lists if each were copied).
fn billion_laughs() -> Vec<u8> {
    let mut p = vec![b']', b'q', 0, b'0'];
    for level in 1..=30u8 {
        p.extend([b']', b'q', level, b'(']);
        for _ in 0..10 {
            p.extend([b'h', level - 1]);
        }
        p.extend([b'e', b'0']);
    }
    p.extend([b'h', 30]);
    p
}

/// Opcodes that push one list nested `depth` deep.
fn nested_lists(depth: usize) -> Vec<u8> {
    let mut p = vec![b']'; depth];
    p.extend(std::iter::repeat_n(b'a', depth - 1));
    p
}

/// A pickle of `value` alone.
fn pickle_of(value: &[u8]) -> Vec<u8> {
    let mut p = vec![0x80, 2];
    p.extend(value);
    p.push(b'.');
    archive(&p, &[])
}

/// A valid view whose field `extra` holds `value`.
fn data_with(value: Vec<u8>) -> Vec<u8> {
    pyg_data(&[
        ("y", PtField::Tensor(PtTensor::float(vec![1.0, 2.0], &[2]))),
        (
            "pos",
            PtField::Tensor(PtTensor::float(
                vec![0.0, 1.0, 9.0, 1.0, 1.0, 12.0],
                &[2, 3],
            )),
        ),
        (
            "pos_world",
            PtField::Tensor(PtTensor::float(
                vec![9.0, 0.0, 0.0, 12.0, -1.0, 0.0],
                &[2, 3],
            )),
        ),
        ("extra", PtField::Pickle(value)),
    ])
}

#[test]
fn a_pickle_billion_laughs_is_refused_within_its_memory() {
    let why = "builds more than";
    refused_as_pair_11(&pickle_of(&billion_laughs()), why);
    refused_as_pair_11(&data_with(billion_laughs()), why);
}

#[test]
fn deeply_nested_lists_are_refused_without_overflowing_the_stack() {
    let why = "nests values more than 200 deep";
    refused_as_pair_11(&pickle_of(&nested_lists(1_000_000)), why);
    refused_as_pair_11(&data_with(nested_lists(1_000_000)), why);
}

#[test]
fn a_tensor_larger_than_its_storage_is_refused_before_it_is_allocated() {
    let huge = PtTensor::float(vec![0.5; 4], &[2, 2]).declared(&[1 << 40, 900]);
    let bytes = pyg_data(&[
        ("y", PtField::Tensor(PtTensor::float(vec![1.0, 2.0], &[2]))),
        ("x", PtField::Tensor(huge)),
    ]);
    refused_as_pair_11(&bytes, "holds more values than the file has bytes");
    // Within the file's size but beyond its storage: refused by the view.
    let long = PtTensor::float(vec![0.5; 4], &[2, 2]).declared(&[2, 900]);
    let bytes = pyg_data(&[("x", PtField::Tensor(long))]);
    refused_as_pair_11(&bytes, "reaches outside its storage of 4 values");
}

#[test]
fn splits_with_a_huge_range_convert_the_pairs_that_exist() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let o = convert_split(&fx, "ds", &["test=0..18446744073709551615"]);
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("converted 3 pairs into 1 run:"), "{said}");
    // Ranges that overlap, and one with no pair folder, are refused.
    let o = convert_split(
        &fx,
        "ds2",
        &["validation=0..11", "test=11..18446744073709551615"],
    );
    assert_refused(
        &o,
        "the ranges of validation (0..11) and test (11..18446744073709551615) overlap",
    );
    let o = convert_split(&fx, "ds3", &["validation=0..9", "test=10..12"]);
    assert_refused(&o, "no pair folder of");
}

/// `n`'s view `v` (0: proc_s, 1: proc_t) of pair 11 written as `bytes`.
fn replace_view(fx: &Fixture, v: usize, bytes: Vec<u8>) {
    let view = ["proc_s", "proc_t"][v];
    std::fs::write(fx.path(&format!("src/{view}/11/data.pt")), bytes).unwrap();
}

/// A pair 11 view of objects 1 and 2 with `fields` replacing its own.
fn view_with(fields: Vec<(&str, PtField)>) -> Vec<u8> {
    let mut all: Vec<(&str, PtField)> = vec![
        ("y", PtField::Tensor(PtTensor::float(vec![1.0, 2.0], &[2]))),
        (
            "pos",
            PtField::Tensor(PtTensor::float(
                vec![0.0, 1.0, 9.0, 1.0, 1.0, 12.0],
                &[2, 3],
            )),
        ),
        (
            "pos_world",
            PtField::Tensor(PtTensor::float(
                vec![9.0, 0.0, 0.0, 12.0, -1.0, 0.0],
                &[2, 3],
            )),
        ),
        ("name", PtField::Text("data/proc_s/11/r1_0006".into())),
    ];
    for (name, field) in fields {
        all.retain(|(n, _)| *n != name);
        all.push((name, field));
    }
    pyg_data(&all)
}

fn convert_refuses(fx: &Fixture, why: &str) {
    let o = convert(fx, "ds");
    assert_refused(&o, why);
    assert!(!fx.path("ds").exists());
}

#[test]
fn non_finite_appearance_values_are_refused_by_convert() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let x = vec![0.5, f64::NAN, 0.5, 0.5, 0.5, 0.5, 0.5, f64::INFINITY];
    let x = PtField::Tensor(PtTensor::float(x, &[2, 4]));
    replace_view(&fx, 1, view_with(vec![("x", x)]));
    convert_refuses(
        &fx,
        "its 'x' holds NaN in row 0, column 1 (appearance values must be finite)",
    );
}

#[test]
fn wrong_dtypes_are_refused_by_convert() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let pos = PtTensor::float(vec![0.0, 1.0, 1.0, 1.0, 1.0, 0.0], &[2, 3]).stored_as("BoolStorage");
    replace_view(&fx, 1, view_with(vec![("pos", PtField::Tensor(pos))]));
    convert_refuses(&fx, "its 'pos' holds bool values, not floating point");
    let label = PtTensor::float(vec![2.0, 2.5], &[2]);
    replace_view(&fx, 1, view_with(vec![("label", PtField::Tensor(label))]));
    convert_refuses(&fx, "its 'label' holds 2.5 in row 1, not an integer");
    // Half, bfloat16 and int8 tensors are read as what they hold.
    let pos =
        PtTensor::float(vec![0.0, 1.0, 9.0, 1.0, 1.0, 12.0], &[2, 3]).stored_as("HalfStorage");
    let y = PtTensor::float(vec![101.0, 102.0], &[2]).stored_as("CharStorage");
    let label = PtTensor::float(vec![2.0, 0.0], &[2]).stored_as("CharStorage");
    let world =
        PtTensor::float(vec![9.0, 0.0, 0.0, 12.0, -1.0, 0.0], &[2, 3]).stored_as("BFloat16Storage");
    replace_view(
        &fx,
        1,
        view_with(vec![
            ("pos", PtField::Tensor(pos)),
            ("y", PtField::Tensor(y)),
            ("label", PtField::Tensor(label)),
            ("pos_world", PtField::Tensor(world)),
        ]),
    );
    assert_ok(&convert(&fx, "ds"));
}

#[test]
fn a_long_y_or_a_short_label_is_refused_as_what_it_is() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let y = PtTensor::float(vec![1.0, 2.0, 3.0], &[3]);
    replace_view(&fx, 1, view_with(vec![("y", PtField::Tensor(y))]));
    convert_refuses(
        &fx,
        "its 'pos' has shape [2, 3], not [3, 3] (its 'y' names 3 objects",
    );
    let label = PtTensor::int(vec![2.0], &[1]);
    replace_view(&fx, 1, view_with(vec![("label", PtField::Tensor(label))]));
    convert_refuses(
        &fx,
        "its 'label' has shape [1], not [2] (one class per object of 'y')",
    );
}

#[test]
fn malformed_or_differing_names_are_refused_by_convert() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    for (name, why) in [
        (
            "data/proc_s/11/r1",
            "its 'name' is \"data/proc_s/11/r1\", not <...>/<recording>_<frame>",
        ),
        ("", "its 'name' is \"\", not <...>/<recording>_<frame>"),
        ("r1_x", "not <...>/<recording>_<frame>"),
    ] {
        replace_view(
            &fx,
            0,
            view_with(vec![("name", PtField::Text(name.into()))]),
        );
        convert_refuses(&fx, why);
    }
    let both = |s: &str, t: &str| {
        replace_view(&fx, 0, view_with(vec![("name", PtField::Text(s.into()))]));
        replace_view(&fx, 1, view_with(vec![("name", PtField::Text(t.into()))]));
    };
    both("data/proc_s/11/r1_0006", "data/proc_t/11/r2_0006");
    convert_refuses(
        &fx,
        "pair 11: its views name different frames (proc_s r1_6, proc_t r2_6)",
    );
    let number = PtField::Pickle(vec![b'K', 7]);
    replace_view(&fx, 0, view_with(vec![("name", number)]));
    convert_refuses(&fx, "its 'name' is not a text");
}

#[test]
fn a_view_without_detections_is_left_out_and_counted() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    replace_view(
        &fx,
        1,
        view_with(vec![
            ("y", PtField::Tensor(PtTensor::float(vec![], &[0]))),
            ("pos", PtField::Tensor(PtTensor::float(vec![], &[0, 3]))),
            (
                "pos_world",
                PtField::Tensor(PtTensor::float(vec![], &[0, 3])),
            ),
        ]),
    );
    let o = convert(&fx, "ds");
    assert_ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("converted 2 pairs into 2 runs (1 pair left out: a vehicle saw nothing, e.g. pair 11 in proc_t)"),
        "{said}"
    );
    assert_ok(&fx.coid(&["dataset", fx.path("ds").to_str().unwrap()]));
}

#[test]
fn a_view_without_world_positions_is_refused_by_convert() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let bytes = pyg_data(&[
        ("y", PtField::Tensor(PtTensor::float(vec![1.0, 2.0], &[2]))),
        (
            "pos",
            PtField::Tensor(PtTensor::float(
                vec![0.0, 1.0, 9.0, 1.0, 1.0, 12.0],
                &[2, 3],
            )),
        ),
        ("name", PtField::Text("data/proc_t/11/r1_0006".into())),
    ]);
    replace_view(&fx, 1, bytes);
    convert_refuses(&fx, "proc_t/11/data.pt: it has no 'pos_world'");
}

#[test]
fn unknown_object_ids_are_never_paired() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let y = |ids: Vec<f64>| PtField::Tensor(PtTensor::float(ids, &[2]));
    replace_view(&fx, 0, view_with(vec![("y", y(vec![-1.0, 5.0]))]));
    replace_view(&fx, 1, view_with(vec![("y", y(vec![-1.0, -1.0]))]));
    assert_ok(&convert_split(&fx, "ds", &["test=11..11"]));
    let pairs = read_parquet(&fx.path("ds/true_pairs.parquet"));
    assert_eq!(pairs.height(), 0, "{pairs}");
    assert_ok(&fx.coid(&["dataset", fx.path("ds").to_str().unwrap()]));
}

#[test]
fn convert_refuses_bad_views_names_and_sigmas_in_one_line() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let src = fx.path("src");
    let base = ["convert", "pyg", src.to_str().unwrap(), "-q", "-o", "ds"];
    let with = |extra: &[&str]| {
        let mut args = base.to_vec();
        args.extend(["--splits", "test=10..12"]);
        args.extend(extra);
        fx.coid(&args)
    };
    let o = with(&["--views", "proc_s", "proc_s"]);
    assert_refused(&o, "--views names proc_s twice");
    for name in ["../x/y", "", "a\nb"] {
        let o = with(&["--name", name]);
        assert_refused(&o, "is not a plain word");
    }
    let o = with(&["--gps-sigma-m", "-1"]);
    assert_refused(&o, "--gps-sigma-m must be a number >= 0, not -1");
    assert_eq!(stderr(&o).trim_end().lines().count(), 1, "{}", stderr(&o));
}

#[test]
fn splits_that_cut_a_recording_are_warned_about() {
    let fx = Fixture::new();
    write_pairs(&fx.path("src"));
    let o = convert_split(&fx, "ds", &["validation=10..10", "test=11..12"]);
    assert_ok(&o);
    assert!(
        stderr(&o).contains("warning: --splits cuts recording dmgm/r1 between validation and test"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_pt_archive_with_two_pickles_is_refused() {
    let one = view(
        "data/proc_t/11/r1_0006",
        &[1, 2],
        &[(0.0, 9.0), (1.0, 12.0)],
        (0.0, 0.0),
        0.0,
    );
    let mut zip = ::zip::ZipArchive::new(std::io::Cursor::new(one)).unwrap();
    let mut pickle = Vec::new();
    std::io::Read::read_to_end(&mut zip.by_name("archive/data.pkl").unwrap(), &mut pickle).unwrap();
    let mut w = ::zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = ::zip::write::SimpleFileOptions::default()
        .compression_method(::zip::CompressionMethod::Stored);
    for root in ["archive", "other"] {
        w.start_file(format!("{root}/data.pkl"), opts).unwrap();
        std::io::Write::write_all(&mut w, &pickle).unwrap();
    }
    refused_as_pair_11(
        &w.finish().unwrap().into_inner(),
        "the archive holds 2 pickles",
    );
}
