//! Gutter dilation of a whole texture: texels next to a chart take their covered neighbours'
//! mean, so bilinear lookups near a chart edge never read the background.

use crate::{Error, Result};
use rayon::prelude::*;
use std::ops::{Add, Mul};

/// Fills gutter texels from covered ones for output textures: each pass gives every
/// uncovered texel with a covered 8-neighbour the average of those neighbours, so after `n`
/// passes every texel within `n` texels of a chart holds surface values and filtered
/// lookups never mix in the background. Returns the grown coverage mask.
pub fn dilate<T>(
    values: &mut [T],
    covered: &[bool],
    width: u32,
    height: u32,
    iterations: u32,
) -> Result<Vec<bool>>
where
    T: Copy + Send + Sync + Add<Output = T> + Mul<f32, Output = T>,
{
    let (w, h) = (width as usize, height as usize);
    if values.len() != w * h || covered.len() != w * h {
        return Err(Error::internal(format!(
            "dilate: {} values and {} mask entries for a {width}x{height} texture",
            values.len(),
            covered.len()
        )));
    }
    let mut mask = covered.to_vec();
    if w == 0 || h == 0 {
        return Ok(mask);
    }
    for _ in 0..iterations {
        let (old_v, old_m) = (values.to_vec(), mask.clone());
        let filled: usize = values
            .par_chunks_mut(w)
            .zip(mask.par_chunks_mut(w))
            .enumerate()
            .map(|(y, (vrow, mrow))| {
                let mut n = 0;
                for x in 0..w {
                    if old_m[y * w + x] {
                        continue;
                    }
                    let mut sum: Option<T> = None;
                    let mut count = 0u32;
                    for ny in y.saturating_sub(1)..(y + 2).min(h) {
                        for nx in x.saturating_sub(1)..(x + 2).min(w) {
                            let j = ny * w + nx;
                            if old_m[j] {
                                sum = Some(sum.map_or(old_v[j], |s| s + old_v[j]));
                                count += 1;
                            }
                        }
                    }
                    if let Some(s) = sum {
                        vrow[x] = s * (1.0 / count as f32);
                        mrow[x] = true;
                        n += 1;
                    }
                }
                n
            })
            .sum();
        if filled == 0 {
            break;
        }
    }
    Ok(mask)
}
