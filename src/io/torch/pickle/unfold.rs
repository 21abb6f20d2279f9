//! The machine's result as a tree of values, bounded in size and depth.

use super::machine::{Item, Obj};
use super::value::{PickleError, Value};
use super::{MAX_DEPTH, object_budget};

/// The machine's result unfolded into a tree of [`Value`]s, counting each
/// value against the budget and each level against [`MAX_DEPTH`].
pub(super) struct Unfold<'a> {
    arena: &'a [Obj],
    left: usize,
    bytes: usize,
    /// The objects being unfolded, outermost first.
    path: Vec<usize>,
}

impl<'a> Unfold<'a> {
    /// An unfolding of `arena`'s objects, for a pickle of `bytes` bytes.
    pub(super) fn new(arena: &'a [Obj], bytes: usize) -> Self {
        Unfold {
            arena,
            left: object_budget(bytes),
            bytes,
            path: Vec::new(),
        }
    }

    fn charge(&mut self, n: usize) -> Result<(), PickleError> {
        self.left = self.left.checked_sub(n).ok_or(PickleError::Expands {
            limit: object_budget(self.bytes),
            bytes: self.bytes,
        })?;
        Ok(())
    }

    fn all(&mut self, items: &[Item], depth: usize) -> Result<Vec<Value>, PickleError> {
        items.iter().map(|&i| self.value(i, depth + 1)).collect()
    }

    pub(super) fn value(&mut self, item: Item, depth: usize) -> Result<Value, PickleError> {
        if depth > MAX_DEPTH {
            return Err(PickleError::TooDeep);
        }
        self.charge(1)?;
        let k = match item {
            Item::None => return Ok(Value::None),
            Item::Bool(b) => return Ok(Value::Bool(b)),
            Item::Int(i) => return Ok(Value::Int(i)),
            Item::Float(x) => return Ok(Value::Float(x)),
            Item::Global(g) => return Ok(Value::Global(g)),
            Item::Obj(k) => k,
        };
        if self.path.contains(&k) {
            return Ok(Value::Ancestor);
        }
        self.path.push(k);
        let v = self.object(k, depth);
        self.path.pop();
        v
    }

    fn object(&mut self, k: usize, depth: usize) -> Result<Value, PickleError> {
        let arena = self.arena;
        Ok(match &arena[k] {
            Obj::Text(s) => {
                self.charge(s.len() / 16)?;
                Value::Text(s.clone())
            }
            Obj::Bytes(b) => {
                self.charge(b.len() / 16)?;
                Value::Bytes(b.clone())
            }
            Obj::Tuple(items) => Value::Tuple(self.all(items, depth)?),
            Obj::List(items) => Value::List(self.all(items, depth)?),
            Obj::Dict(items) => Value::Dict(
                items
                    .iter()
                    .map(|&(k, v)| Ok((self.value(k, depth + 1)?, self.value(v, depth + 1)?)))
                    .collect::<Result<_, PickleError>>()?,
            ),
            Obj::Object { class, state } => Value::Object {
                class: *class,
                state: match state {
                    Some(s) => Some(Box::new(self.value(*s, depth + 1)?)),
                    None => None,
                },
            },
            Obj::Storage(s) => Value::Storage {
                dtype: s.0,
                key: s.1.clone(),
                numel: s.2,
            },
            Obj::Tensor(t) => Value::Tensor(t.as_ref().clone()),
        })
    }
}
