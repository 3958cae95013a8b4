//! A glTF accessor's byte ranges checked against the loaded buffers before the `gltf` crate
//! reads it: its reader computes `offset + stride * (count - 1) + size` unchecked (a
//! `count: 0` or a huge count panics in debug builds and wraps in release) and asserts that a
//! stride is no shorter than an element, so a malformed file must be refused here first.

use ::gltf::buffer::View;
use ::gltf::Accessor;

/// Why `acc` cannot be read from `buffers` (one line), or `None` when every byte it names
/// lies inside its buffer view and every view inside its buffer.
pub(super) fn layout_error(acc: &Accessor, buffers: &[Vec<u8>]) -> Option<String> {
    let count = acc.count();
    if count == 0 {
        return Some("count is 0 (at least 1 is required)".into());
    }
    let total: usize = buffers.iter().map(Vec::len).sum();
    if count > total {
        return Some(format!(
            "count {count} is more than the {total} bytes of all buffers"
        ));
    }
    if let Some(view) = acc.view() {
        let e = range_error(&view, acc.offset(), count, acc.size(), buffers);
        if e.is_some() {
            return e;
        }
    }
    acc.sparse()
        .and_then(|s| sparse_error(&s, count, acc.size(), buffers))
}

/// The sparse substitution's indices and values checked as [`layout_error`] checks a view.
fn sparse_error(
    s: &::gltf::accessor::sparse::Sparse,
    count: usize,
    size: usize,
    buffers: &[Vec<u8>],
) -> Option<String> {
    let n = s.count();
    if n == 0 || n > count {
        return Some(format!("sparse.count {n} is not in 1..={count}"));
    }
    let (idx, val) = (s.indices(), s.values());
    let index_size = idx.index_type().size();
    range_error(&idx.view(), idx.offset(), n, index_size, buffers)
        .map(|e| format!("sparse.indices: {e}"))
        .or_else(|| {
            range_error(&val.view(), val.offset(), n, size, buffers)
                .map(|e| format!("sparse.values: {e}"))
        })
}

/// Why `count` elements of `size` bytes from `offset` in `view` (at its stride) do not fit
/// the view, or the view does not fit its buffer.
fn range_error(
    view: &View,
    offset: usize,
    count: usize,
    size: usize,
    buffers: &[Vec<u8>],
) -> Option<String> {
    let v = view.index();
    let buf = view.buffer().index();
    let held = buffers.get(buf).map_or(0, Vec::len);
    let view_end = view.offset().checked_add(view.length());
    if view_end.is_none_or(|end| end > held) {
        return Some(format!(
            "bufferViews[{v}] (byteOffset {}, byteLength {}) lies outside buffers[{buf}] \
             ({held} bytes)",
            view.offset(),
            view.length()
        ));
    }
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Some(format!(
            "bufferViews[{v}] byteStride {stride} is shorter than an element ({size} bytes)"
        ));
    }
    let need = stride
        .checked_mul(count - 1)
        .and_then(|n| n.checked_add(offset))
        .and_then(|n| n.checked_add(size));
    match need {
        Some(need) if need <= view.length() => None,
        _ => Some(format!(
            "{count} elements of {size} bytes from byteOffset {offset} (stride {stride}) do \
             not fit bufferViews[{v}] ({} bytes)",
            view.length()
        )),
    }
}
