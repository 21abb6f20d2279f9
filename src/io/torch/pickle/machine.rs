//! The pickle machine: opcodes run against a stack, a memo and an arena
//! of objects, without recursion; a memo reference shares its object.

use std::collections::HashMap;

use super::value::{DType, Global, PickleError, TensorView};

/// The most items one dict may hold (a `Data` has a few dozen fields).
const MAX_DICT_ITEMS: usize = 4096;

/// The most dimensions a tensor may have (torch's own limit).
const MAX_DIMS: usize = 64;

/// Runs `bytes` to its STOP: the item it leaves and the arena it names.
pub(super) fn run(bytes: &[u8]) -> Result<(Item, Vec<Obj>), PickleError> {
    let mut m = Machine {
        bytes,
        at: 0,
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
        arena: Vec::new(),
    };
    let root = m.run()?;
    Ok((root, m.arena))
}

/// What the machine's stack and memo hold: a plain value, or an object of
/// the arena, shared by every item that names it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Item {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Global(Global),
    Obj(usize),
}

/// An object the machine built (32 bytes: the rare large ones boxed, as
/// an opcode byte may make one).
pub(super) enum Obj {
    Text(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Item>),
    List(Vec<Item>),
    Dict(Vec<(Item, Item)>),
    Object { class: Global, state: Option<Item> },
    Storage(Box<(DType, String, usize)>),
    Tensor(Box<TensorView>),
}

const _: () = assert!(std::mem::size_of::<Obj>() == 32);

struct Machine<'a> {
    bytes: &'a [u8],
    at: usize,
    stack: Vec<Item>,
    marks: Vec<usize>,
    memo: HashMap<u32, Item>,
    arena: Vec<Obj>,
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

    /// `o` as a new object of the arena.
    fn alloc(&mut self, o: Obj) -> Item {
        self.arena.push(o);
        Item::Obj(self.arena.len() - 1)
    }

    fn push_new(&mut self, o: Obj) {
        let item = self.alloc(o);
        self.stack.push(item);
    }

    fn obj(&self, item: Item) -> Option<&Obj> {
        match item {
            Item::Obj(k) => self.arena.get(k),
            _ => None,
        }
    }

    fn text_of(&self, item: Item) -> Option<&str> {
        match self.obj(item) {
            Some(Obj::Text(s)) => Some(s),
            _ => None,
        }
    }

    fn pop(&mut self) -> Result<Item, PickleError> {
        self.stack
            .pop()
            .ok_or_else(|| self.malformed("an empty stack"))
    }

    fn pop_mark(&mut self) -> Result<Vec<Item>, PickleError> {
        let mark = self.marks.pop().ok_or_else(|| self.malformed("no mark"))?;
        if mark > self.stack.len() {
            return Err(self.malformed("a mark above the stack"));
        }
        Ok(self.stack.split_off(mark))
    }

    fn top(&self) -> Result<Item, PickleError> {
        self.stack
            .last()
            .copied()
            .ok_or_else(|| self.malformed("an empty stack"))
    }

    fn put(&mut self, key: u32) -> Result<(), PickleError> {
        let v = self.top()?;
        self.memo.insert(key, v);
        Ok(())
    }

    fn get(&mut self, key: u32) -> Result<(), PickleError> {
        let v = self
            .memo
            .get(&key)
            .copied()
            .ok_or_else(|| self.malformed(format!("memo {key} was never put")))?;
        self.stack.push(v);
        Ok(())
    }

    fn global(&mut self, module: &str, name: &str) -> Result<(), PickleError> {
        let g = Global::named(module, name)?;
        self.stack.push(Item::Global(g));
        Ok(())
    }

    fn run(&mut self) -> Result<Item, PickleError> {
        loop {
            let op = self.take(1)?[0];
            if op == b'.' {
                return self.pop();
            }
            self.step(op)?;
        }
    }

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
                let v = self.top()?;
                self.stack.push(v);
            }
            b'N' => self.stack.push(Item::None),
            0x88 => self.stack.push(Item::Bool(true)),
            0x89 => self.stack.push(Item::Bool(false)),
            b'J' | b'K' | b'M' | 0x8a | b'G' => self.number(op)?,
            b'X' | 0x8c | 0x8d | b'C' | b'B' | 0x8e => self.text_or_bytes(op)?,
            b')' | b't' | 0x85..=0x87 | b']' | b'l' | b'a' | b'e' | b'}' | b'd' | b's' | b'u' => {
                self.container(op)?
            }
            b'c' | 0x93 | b'q' | b'r' | 0x94 | b'h' | b'j' => self.name_or_memo(op)?,
            b'Q' | b'R' | 0x81 | b'b' => self.object(op)?,
            other => return Err(PickleError::Opcode(other)),
        }
        Ok(())
    }

    fn number(&mut self, op: u8) -> Result<(), PickleError> {
        let v = match op {
            b'J' => Item::Int(i64::from(self.uint(4)? as u32 as i32)),
            b'K' => Item::Int(self.uint(1)? as i64),
            b'M' => Item::Int(self.uint(2)? as i64),
            b'G' => {
                let s = self.take(8)?;
                Item::Float(f64::from_be_bytes(s.try_into().expect("8 bytes")))
            }
            _ => {
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
                Item::Int(v)
            }
        };
        self.stack.push(v);
        Ok(())
    }

    fn text_or_bytes(&mut self, op: u8) -> Result<(), PickleError> {
        let o = match op {
            b'X' => {
                let n = self.len(4)?;
                Obj::Text(self.text(n)?)
            }
            0x8c => {
                let n = self.len(1)?;
                Obj::Text(self.text(n)?)
            }
            0x8d => {
                let n = self.len(8)?;
                Obj::Text(self.text(n)?)
            }
            _ => {
                let n = match op {
                    b'C' => self.len(1)?,
                    b'B' => self.len(4)?,
                    _ => self.len(8)?,
                };
                Obj::Bytes(self.take(n)?.to_vec())
            }
        };
        self.push_new(o);
        Ok(())
    }

    fn container(&mut self, op: u8) -> Result<(), PickleError> {
        match op {
            b')' => self.push_new(Obj::Tuple(Vec::new())),
            b't' => {
                let items = self.pop_mark()?;
                self.push_new(Obj::Tuple(items));
            }
            0x85..=0x87 => {
                let n = usize::from(op - 0x84);
                if self.stack.len() < n {
                    return Err(self.malformed("a tuple longer than the stack"));
                }
                let items = self.stack.split_off(self.stack.len() - n);
                self.push_new(Obj::Tuple(items));
            }
            b']' => self.push_new(Obj::List(Vec::new())),
            b'l' => {
                let items = self.pop_mark()?;
                self.push_new(Obj::List(items));
            }
            b'a' => {
                let v = self.pop()?;
                self.append(vec![v])?;
            }
            b'e' => {
                let items = self.pop_mark()?;
                self.append(items)?;
            }
            b'}' => self.push_new(Obj::Dict(Vec::new())),
            b'd' => {
                let items = self.pop_mark()?;
                let d = self.pairs(items)?;
                let dict = self.alloc(Obj::Dict(Vec::new()));
                self.stack.push(dict);
                self.set_items(d)?;
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                self.set_items(vec![(k, v)])?;
            }
            _ => {
                let items = self.pop_mark()?;
                let d = self.pairs(items)?;
                self.set_items(d)?;
            }
        }
        Ok(())
    }

    fn name_or_memo(&mut self, op: u8) -> Result<(), PickleError> {
        match op {
            b'c' => {
                let module = self.line()?;
                let name = self.line()?;
                self.global(&module, &name)?;
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (Some(module), Some(name)) = (self.text_of(module), self.text_of(name)) else {
                    return Err(self.malformed("STACK_GLOBAL without two texts"));
                };
                let (module, name) = (module.to_owned(), name.to_owned());
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
            _ => {
                let k = self.uint(4)? as u32;
                self.get(k)?;
            }
        }
        Ok(())
    }

    fn object(&mut self, op: u8) -> Result<(), PickleError> {
        match op {
            b'Q' => {
                let pid = self.pop()?;
                let v = self.storage(pid)?;
                self.push_new(v);
            }
            b'R' => {
                let args = self.pop()?;
                let callable = self.pop()?;
                let v = self.reduce(callable, args)?;
                self.push_new(v);
            }
            0x81 => {
                let _args = self.pop()?;
                let class = self.pop()?;
                let v = self.instance(class)?;
                self.push_new(v);
            }
            _ => {
                let state = self.pop()?;
                let top = self.top()?;
                let at = self.at;
                match top {
                    Item::Obj(k) => match &mut self.arena[k] {
                        Obj::Object { state: s, .. } => *s = Some(state),
                        Obj::Dict(_) if state == Item::None => {}
                        _ => {
                            return Err(PickleError::Malformed {
                                at,
                                why: "BUILD on a value that is not an object".into(),
                            });
                        }
                    },
                    _ => return Err(self.malformed("BUILD on a value that is not an object")),
                }
            }
        }
        Ok(())
    }

    fn append(&mut self, items: Vec<Item>) -> Result<(), PickleError> {
        let top = self.top()?;
        match top {
            Item::Obj(k) if matches!(self.arena[k], Obj::List(_)) => {
                if let Obj::List(l) = &mut self.arena[k] {
                    l.extend(items);
                }
                Ok(())
            }
            _ => Err(self.malformed("APPEND to a value that is not a list")),
        }
    }

    fn pairs(&self, items: Vec<Item>) -> Result<Vec<(Item, Item)>, PickleError> {
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

    /// Whether two dict keys are equal: texts by content, other objects
    /// by identity, plain values by value.
    fn same_key(&self, a: Item, b: Item) -> bool {
        match (self.text_of(a), self.text_of(b)) {
            (Some(x), Some(y)) => x == y,
            _ => a == b,
        }
    }

    fn set_items(&mut self, items: Vec<(Item, Item)>) -> Result<(), PickleError> {
        let top = self.top()?;
        let Item::Obj(d) = top else {
            return Err(self.malformed("SETITEM on a value that is not a dict"));
        };
        for (k, v) in items {
            let Obj::Dict(entries) = &self.arena[d] else {
                return Err(self.malformed("SETITEM on a value that is not a dict"));
            };
            let slot = entries.iter().position(|(old, _)| self.same_key(*old, k));
            let full = entries.len() >= MAX_DICT_ITEMS;
            let Obj::Dict(entries) = &mut self.arena[d] else {
                unreachable!("a dict above")
            };
            match slot {
                Some(s) => entries[s].1 = v,
                None if full => {
                    return Err(
                        self.malformed(format!("a dict of more than {MAX_DICT_ITEMS} items"))
                    );
                }
                None => entries.push((k, v)),
            }
        }
        Ok(())
    }

    fn instance(&self, class: Item) -> Result<Obj, PickleError> {
        match class {
            Item::Global(g @ (Global::PygData | Global::PygStorage | Global::PygAttrClass)) => {
                Ok(Obj::Object {
                    class: g,
                    state: None,
                })
            }
            Item::Global(Global::OrderedDict) => Ok(Obj::Dict(Vec::new())),
            _ => Err(self.malformed("NEWOBJ of something that is not a class coid builds")),
        }
    }

    /// A persistent id: `('storage', <Type>Storage, key, location, numel)`.
    fn storage(&self, pid: Item) -> Result<Obj, PickleError> {
        let Some(Obj::Tuple(items)) = self.obj(pid) else {
            return Err(self.malformed("a persistent id that is not a tuple"));
        };
        match items.as_slice() {
            [
                kind,
                Item::Global(Global::Storage(dtype)),
                key,
                location,
                Item::Int(numel),
            ] if self.text_of(*kind) == Some("storage")
                && self.text_of(*location).is_some()
                && *numel >= 0 =>
            {
                let key = self
                    .text_of(*key)
                    .ok_or_else(|| self.malformed("a persistent id whose key is not a text"))?;
                let numel = usize::try_from(*numel)
                    .map_err(|_| self.malformed("a storage size out of range"))?;
                Ok(Obj::Storage(Box::new((*dtype, key.to_owned(), numel))))
            }
            _ => Err(self.malformed("a persistent id that is not a tensor storage")),
        }
    }

    fn reduce(&self, callable: Item, args: Item) -> Result<Obj, PickleError> {
        let Some(Obj::Tuple(args)) = self.obj(args) else {
            return Err(self.malformed("REDUCE arguments that are not a tuple"));
        };
        match callable {
            Item::Global(Global::OrderedDict) if args.is_empty() => Ok(Obj::Dict(Vec::new())),
            Item::Global(Global::RebuildTensor) => self.tensor(args),
            Item::Global(g @ (Global::PygData | Global::PygStorage)) => Ok(Obj::Object {
                class: g,
                state: None,
            }),
            _ => Err(self.malformed("REDUCE of something coid does not build")),
        }
    }

    /// A tuple of at most [`MAX_DIMS`] integers >= 0 (a size or a stride).
    fn dims(&self, item: Item, what: &str) -> Result<Vec<usize>, PickleError> {
        let Some(Obj::Tuple(items)) = self.obj(item) else {
            return Err(self.malformed(format!("a tensor's {what} is not a tuple")));
        };
        if items.len() > MAX_DIMS {
            return Err(self.malformed(format!(
                "a tensor of {} dimensions (torch allows {MAX_DIMS})",
                items.len()
            )));
        }
        items
            .iter()
            .map(|x| match x {
                Item::Int(i) => usize::try_from(*i)
                    .map_err(|_| self.malformed(format!("a tensor's {what} holds {i} (negative)"))),
                _ => Err(self.malformed(format!(
                    "a tensor's {what} holds a value that is not an integer"
                ))),
            })
            .collect()
    }

    /// `_rebuild_tensor_v2(storage, offset, size, stride, requires_grad,
    /// hooks[, metadata])`.
    fn tensor(&self, args: &[Item]) -> Result<Obj, PickleError> {
        let [storage, offset, size, stride, ..] = args else {
            return Err(self.malformed("a tensor rebuilt from fewer than four arguments"));
        };
        let Some(Obj::Storage(storage)) = self.obj(*storage) else {
            return Err(self.malformed("a tensor rebuilt from something that is not a storage"));
        };
        let Item::Int(offset) = *offset else {
            return Err(self.malformed("a tensor's offset is not an integer"));
        };
        let offset = usize::try_from(offset)
            .map_err(|_| self.malformed(format!("a tensor's offset is {offset} (negative)")))?;
        let (shape, stride) = (self.dims(*size, "size")?, self.dims(*stride, "stride")?);
        if shape.len() != stride.len() {
            return Err(self.malformed("a tensor's size and stride differ in length"));
        }
        let (dtype, key, numel) = storage.as_ref();
        Ok(Obj::Tensor(Box::new(TensorView {
            dtype: *dtype,
            key: key.clone(),
            numel: *numel,
            offset,
            shape,
            stride,
        })))
    }
}
