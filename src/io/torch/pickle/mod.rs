//! A pickle reader that only builds values: the opcodes of protocols 2 to
//! 5 that make numbers, text, tuples, lists and dicts, and the few globals
//! a PyTorch Geometric `Data` saved with `torch.save` names ([`Global`]).
//! Every other global (`os.system`, `builtins.eval`, any class) is refused
//! by name before anything is called: a file from elsewhere cannot make
//! this reader run code, because this reader never runs any.
//!
//! Nor can a file make it use more than a small multiple of its size. The
//! machine ([`machine`]) keeps what it builds in one arena and a memo
//! reference (`GET`, `DUP`) shares an object as Python does, so running a
//! pickle allocates at most about 64 bytes per opcode byte, with no
//! recursion. The result is then unfolded ([`unfold`]) into a tree of
//! [`Value`]s, where a shared object counts once per use and a reference
//! to an object that holds it (a cycle, as PyG's `_parent`) is left as
//! [`Value::Ancestor`]: that tree may hold at most [`object_budget`]
//! values and nest at most [`MAX_DEPTH`] deep, and a pickle that would
//! build more (a "billion laughs" of lists that repeat one another, a
//! million nested lists) is refused with its numbers.

/// The deepest a value may nest (a PyG `Data` nests about six deep).
pub const MAX_DEPTH: usize = 200;

/// The most values the tree of a pickle of `bytes` bytes may hold: one
/// per byte (every value of an unshared pickle costs at least one opcode
/// byte) and a floor for the few small globals and storages a `Data`
/// names again and again.
pub fn object_budget(bytes: usize) -> usize {
    4096 + bytes
}

mod machine;
mod unfold;
mod value;

pub use value::{DType, Global, PickleError, TensorView, Value};

/// Reads a pickle into a [`Value`], building nothing but values.
pub fn read(bytes: &[u8]) -> Result<Value, PickleError> {
    let (root, arena) = machine::run(bytes)?;
    unfold::Unfold::new(&arena, bytes.len()).value(root, 0)
}
