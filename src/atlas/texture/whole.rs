//! Whole textures from tiles and back: the one read and the one write between a slot's
//! tiles in the stores and its row-major `width x height` texture, for the passes that need a
//! texture's neighbourhoods (fill, smoothing, dilation, albedo lookups, outputs). Every other
//! stage works tile by tile.

use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom};
use crate::base::error::Result;
use bytemuck::Pod;

/// Slot `slot`'s texture assembled from `store` and the geometry beside it: `f(record,
/// geometry)` per texel, row-major. Each tile is read once.
pub fn read_slot<S, V>(
    layout: &Layout,
    slot: usize,
    store: &TileStore<S>,
    geom: &TileStore<TexelGeom>,
    f: impl Fn(&S, &TexelGeom) -> V,
) -> Result<Vec<V>>
where
    S: Pod + Send + Sync,
    V: Default + Clone,
{
    let st = &layout.slots[slot];
    let mut out = vec![V::default(); st.width as usize * st.height as usize];
    for tile in layout.slot_tiles(slot) {
        let (recs, g) = (
            store.read_tile(tile as usize)?,
            geom.read_tile(tile as usize)?,
        );
        for (off, i) in layout.span(tile).indices() {
            out[i] = f(&recs[off], &g[off]);
        }
    }
    Ok(out)
}

/// Writes a whole texture back into slot `slot`'s tiles of `store`: `f(record, value)` per
/// texel returns whether it changed the record; tiles without a change are not rewritten.
/// Returns how many records changed.
pub fn write_slot<S, V>(
    layout: &Layout,
    slot: usize,
    store: &mut TileStore<S>,
    values: &[V],
    f: impl Fn(&mut S, &V) -> bool,
) -> Result<u64>
where
    S: Pod + Send + Sync,
{
    let mut changed = 0u64;
    for tile in layout.slot_tiles(slot) {
        let mut recs = store.read_tile(tile as usize)?;
        let mut n = 0u64;
        for (off, i) in layout.span(tile).indices() {
            n += f(&mut recs[off], &values[i]) as u64;
        }
        if n > 0 {
            store.write_tile(tile as usize, &recs)?;
            changed += n;
        }
    }
    Ok(changed)
}

/// The texels within `r` of `(x, y)` in a row-major `width x height` texture, clipped to it:
/// one range of indices per row (the window of the texture-space filters).
pub fn window(
    width: usize,
    height: usize,
    (x, y): (usize, usize),
    r: usize,
) -> impl Iterator<Item = std::ops::Range<usize>> {
    let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(width));
    (y.saturating_sub(r)..(y + r + 1).min(height)).map(move |ny| ny * width + x0..ny * width + x1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::store::flags;

    #[test]
    fn read_then_write_round_trips_every_texel() {
        let dir = tempfile::tempdir().unwrap();
        let layout = Layout::new(4, &[(0, 5, 3), (3, 6, 6)]);
        let n = layout.tile_count as usize;
        let mut store = TileStore::<u32>::create(dir.path().join("s"), n, 16, 0).unwrap();
        let geom = TileStore::<TexelGeom>::create(
            dir.path().join("g"),
            n,
            16,
            TexelGeom {
                flags: flags::COVERED,
                ..Default::default()
            },
        )
        .unwrap();
        for slot in 0..2 {
            let st = layout.slots[slot];
            let vals: Vec<u32> = (0..st.width * st.height)
                .map(|i| 1000 * slot as u32 + i)
                .collect();
            let changed = write_slot(&layout, slot, &mut store, &vals, |r, v| {
                *r = *v;
                true
            })
            .unwrap();
            assert_eq!(changed, vals.len() as u64);
            let back = read_slot(&layout, slot, &store, &geom, |r, g| (*r, g.covered())).unwrap();
            assert_eq!(back.iter().map(|b| b.0).collect::<Vec<_>>(), vals);
            assert!(back.iter().all(|b| b.1));
            // every texel sits where texel_of says
            for t in layout.slot_tiles(slot) {
                let recs = store.read_tile(t as usize).unwrap();
                for (off, x, y) in layout.span(t).texels() {
                    assert_eq!(recs[off], 1000 * slot as u32 + y * st.width + x);
                }
            }
        }
        // nothing changed: nothing rewritten
        let vals = vec![0u32; 36];
        assert_eq!(
            write_slot(&layout, 1, &mut store, &vals, |_, _| false).unwrap(),
            0
        );
    }
}
