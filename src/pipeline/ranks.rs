//! How the ranks of an MPI job (`comm`) share the heavy stages' results, so every rank's state
//! ends each stage identical to a single process's: whole tiles of a store, per-unit results
//! (a tile's sums, a gather chunk's values, rendered rows) gathered to every rank and put back
//! in unit order; a photon batch's deposits sent to the rank that owns their tile. Work unit
//! `u` is computed by rank `u mod N` ([`World::owns`]): the units are fixed by the data and
//! combined in their order, never by the rank count.

use crate::atlas::store::TileStore;
use crate::base::comm::World;
use crate::base::error::{Error, Result};
use crate::stages::indirect::photon::{Deposit, PathCounts, Traced};
use bytemuck::Pod;
use serde::de::DeserializeOwned;
use serde::Serialize;

/// Bytes of tiles one rank contributes to one exchange round at most (rounds bound the memory
/// an exchange takes, whatever the store's size).
const ROUND_BYTES: u64 = 64 << 20;

/// Gather points per work unit of the gather.
pub const GATHER_CHUNK: usize = 256;

/// Makes every tile of `store` current on every rank: each rank's own tiles (`tile mod N`)
/// go to every other, a round of tiles at a time.
pub fn share_tiles<T: Pod + Send + Sync>(world: &World, store: &mut TileStore<T>) -> Result<()> {
    if world.size() == 1 {
        return Ok(());
    }
    let n = store.tile_count();
    let per_round = (ROUND_BYTES / store.tile_stride_bytes().max(1)).max(1) as usize;
    let me = world.rank();
    for start in (0..n).step_by(per_round) {
        let tiles = start..(start + per_round).min(n);
        let mut mine = Vec::new();
        for t in tiles.clone().filter(|&t| world.owns(t as u64)) {
            mine.extend_from_slice(bytemuck::cast_slice(&store.read_tile(t)?));
        }
        let all = world.all_gather(&mine);
        let tile_bytes = store.tile_texels() * std::mem::size_of::<T>();
        for (r, bytes) in all.iter().enumerate().filter(|(r, _)| *r != me) {
            let theirs: Vec<usize> = tiles
                .clone()
                .filter(|&t| world.owner(t as u64) == r)
                .collect();
            if bytes.len() != theirs.len() * tile_bytes {
                return Err(mismatch("tiles", r, bytes.len()));
            }
            for (t, b) in theirs.iter().zip(bytes.chunks_exact(tile_bytes.max(1))) {
                store.write_tile(*t, &bytemuck::pod_collect_to_vec::<u8, T>(b))?;
            }
        }
    }
    Ok(())
}

/// Rank 0's `store` on every rank (a resumed run's restored state), a round at a time.
pub fn broadcast_store<T: Pod + Send + Sync>(
    world: &World,
    store: &mut TileStore<T>,
) -> Result<()> {
    if world.size() == 1 {
        return Ok(());
    }
    let n = store.tile_count();
    let per_round = (ROUND_BYTES / store.tile_stride_bytes().max(1)).max(1) as usize;
    let tile_bytes = store.tile_texels() * std::mem::size_of::<T>();
    for start in (0..n).step_by(per_round) {
        let tiles = start..(start + per_round).min(n);
        let mut mine = Vec::new();
        if world.is_root() {
            for t in tiles.clone() {
                mine.extend_from_slice(bytemuck::cast_slice(&store.read_tile(t)?));
            }
        }
        let bytes = world.broadcast(mine);
        if world.is_root() {
            continue;
        }
        if bytes.len() != tiles.len() * tile_bytes {
            return Err(mismatch("tiles", 0, bytes.len()));
        }
        for (t, b) in tiles.zip(bytes.chunks_exact(tile_bytes.max(1))) {
            store.write_tile(t, &bytemuck::pod_collect_to_vec::<u8, T>(b))?;
        }
    }
    Ok(())
}

/// Every rank's `(unit, bytes)` on every rank, sorted by unit.
fn share_units(world: &World, mine: Vec<(u64, Vec<u8>)>) -> Result<Vec<(u64, Vec<u8>)>> {
    if world.size() == 1 {
        return Ok(mine);
    }
    let mut buf = Vec::new();
    for (u, b) in &mine {
        buf.extend_from_slice(&u.to_le_bytes());
        buf.extend_from_slice(&(b.len() as u64).to_le_bytes());
        buf.extend_from_slice(b);
    }
    drop(mine);
    let mut out = Vec::new();
    for (r, bytes) in world.all_gather(&buf).into_iter().enumerate() {
        let mut rest = &bytes[..];
        while !rest.is_empty() {
            let word = |b: &[u8]| {
                b.get(..8)
                    .map(|w| u64::from_le_bytes(w.try_into().unwrap_or([0; 8])))
            };
            let (Some(u), Some(len)) = (word(rest), rest.get(8..).and_then(word)) else {
                return Err(mismatch("units", r, bytes.len()));
            };
            let body = rest
                .get(16..16 + len as usize)
                .ok_or_else(|| mismatch("units", r, bytes.len()))?;
            out.push((u, body.to_vec()));
            rest = &rest[16 + len as usize..];
        }
    }
    out.sort_by_key(|(u, _)| *u);
    Ok(out)
}

/// Every rank's per-unit results (any serde type) on every rank, in unit order.
pub fn share_serde<T: Serialize + DeserializeOwned>(
    world: &World,
    mine: Vec<(u64, T)>,
) -> Result<Vec<(u64, T)>> {
    if world.size() == 1 {
        return Ok(mine);
    }
    let cfg = bincode::config::standard();
    let enc = mine
        .iter()
        .map(|(u, v)| {
            let b = bincode::serde::encode_to_vec(v, cfg)
                .map_err(|e| Error::internal(format!("sharing results: {e}")))?;
            Ok((*u, b))
        })
        .collect::<Result<Vec<_>>>()?;
    share_units(world, enc)?
        .into_iter()
        .map(|(u, b)| {
            let (v, _) = bincode::serde::decode_from_slice(&b, cfg)
                .map_err(|e| Error::internal(format!("sharing results: {e}")))?;
            Ok((u, v))
        })
        .collect()
}

/// A photon group's batches traced here (batch number, deposits, counters) -> every batch of
/// the group in batch order, each with its counters and the deposits that land in this rank's
/// tiles (`tile mod N`), in photon order: each deposit goes to the one rank that adds it, so a
/// texel sees the additions of one process in the same order. The other tiles' accumulators
/// are stale until [`share_tiles`].
pub fn route_batches(world: &World, mine: Vec<(u64, Traced)>) -> Result<Vec<Traced>> {
    let n = world.size();
    if n == 1 {
        return Ok(mine.into_iter().map(|t| t.1).collect());
    }
    // to each rank, per batch: batch, rays, dropped, deposit count, its deposits
    let mut parts = vec![Vec::new(); n];
    for (b, (deps, c)) in mine {
        let mut to: Vec<Vec<Deposit>> = vec![Vec::new(); n];
        for d in deps {
            to[world.owner(u64::from(d.tile))].push(d);
        }
        for (part, d) in parts.iter_mut().zip(&to) {
            for w in [b, c.rays, c.dropped, d.len() as u64] {
                part.extend_from_slice(&w.to_le_bytes());
            }
            part.extend_from_slice(bytemuck::cast_slice(d));
        }
    }
    let size = std::mem::size_of::<Deposit>();
    let mut out = Vec::new();
    for (r, bytes) in world.all_to_all(parts).into_iter().enumerate() {
        let mut rest = &bytes[..];
        while !rest.is_empty() {
            let word = |i: usize| {
                rest.get(8 * i..8 * i + 8)
                    .map(|w| u64::from_le_bytes(w.try_into().unwrap_or([0; 8])))
            };
            let (Some(b), Some(rays), Some(dropped), Some(k)) =
                (word(0), word(1), word(2), word(3))
            else {
                return Err(mismatch("photon deposits", r, bytes.len()));
            };
            let body = rest
                .get(32..32 + k as usize * size)
                .ok_or_else(|| mismatch("photon deposits", r, bytes.len()))?;
            let deps = bytemuck::pod_collect_to_vec::<u8, Deposit>(body);
            out.push((b, (deps, PathCounts { rays, dropped })));
            rest = &rest[32 + k as usize * size..];
        }
    }
    out.sort_by_key(|(b, _)| *b);
    Ok(out.into_iter().map(|t| t.1).collect())
}

/// The gather's per-point values: each rank computed its own chunks of
/// [`GATHER_CHUNK`] points (zero elsewhere); afterwards every rank has every value.
pub fn share_points(world: &World, values: &mut [glam::Vec3]) -> Result<()> {
    if world.size() == 1 {
        return Ok(());
    }
    let chunks = values.chunks(GATHER_CHUNK).enumerate();
    let mine = chunks
        .filter(|(c, _)| world.owns(*c as u64))
        .map(|(c, v)| (c as u64, bytemuck::cast_slice(v).to_vec()))
        .collect();
    for (c, b) in share_units(world, mine)? {
        let at = c as usize * GATHER_CHUNK;
        let v = bytemuck::pod_collect_to_vec::<u8, glam::Vec3>(&b);
        values
            .get_mut(at..at + v.len())
            .ok_or_else(|| mismatch("gather values", world.owner(c), b.len()))?
            .copy_from_slice(&v);
    }
    Ok(())
}

/// An image computed in units of `unit` consecutive pixels, unit `u` by rank `u mod N`
/// (`None` elsewhere): afterwards every rank has every unit.
pub fn share_pixels(world: &World, img: &mut [Option<glam::Vec3>], unit: usize) -> Result<()> {
    if world.size() == 1 {
        return Ok(());
    }
    let unit = unit.max(1);
    let mine = img
        .chunks(unit)
        .enumerate()
        .filter(|(u, _)| world.owns(*u as u64))
        .map(|(u, px)| {
            let v: Vec<[f32; 4]> = px
                .iter()
                .map(|p| p.map_or([0.0; 4], |p| [p.x, p.y, p.z, 1.0]))
                .collect();
            (u as u64, bytemuck::cast_slice(&v).to_vec())
        })
        .collect();
    for (u, b) in share_units(world, mine)? {
        let at = u as usize * unit;
        let v = bytemuck::pod_collect_to_vec::<u8, [f32; 4]>(&b);
        let dst = img
            .get_mut(at..at + v.len())
            .ok_or_else(|| mismatch("pixels", world.owner(u), b.len()))?;
        for (d, p) in dst.iter_mut().zip(&v) {
            *d = (p[3] != 0.0).then(|| glam::Vec3::new(p[0], p[1], p[2]));
        }
    }
    Ok(())
}

/// A buffer computed in units of `unit` consecutive bytes, unit `u` by rank `u mod N`
/// (anything elsewhere): afterwards every rank has every unit.
pub fn share_bytes(world: &World, buf: &mut [u8], unit: usize) -> Result<()> {
    if world.size() == 1 {
        return Ok(());
    }
    let unit = unit.max(1);
    let mine = buf
        .chunks(unit)
        .enumerate()
        .filter(|(u, _)| world.owns(*u as u64))
        .map(|(u, b)| (u as u64, b.to_vec()))
        .collect();
    for (u, b) in share_units(world, mine)? {
        let at = u as usize * unit;
        buf.get_mut(at..at + b.len())
            .ok_or_else(|| mismatch("bytes", world.owner(u), b.len()))?
            .copy_from_slice(&b);
    }
    Ok(())
}

fn mismatch(what: &str, rank: usize, bytes: usize) -> Error {
    Error::internal(format!(
        "rank {rank} sent {bytes} bytes of {what} that do not fit this rank's layout"
    ))
}
