//! What the refinement passes read and write of a texel, as a record of its own: a pass reads
//! every texel's luminance and weight and writes its luminance (and, in the last pass, its
//! statistics), 28 of the state's 92 bytes. The passes run on a working store of these records,
//! copied from the state before the first pass and back after the last, so each pass streams
//! (and a shared run syncs) under a third of the bytes it would through the state.

use super::{fused_variance, photo_variance, Residual};
use crate::atlas::store::{map_tiles, TexelState, TileStore};
use crate::base::error::Result;
use bytemuck::{Pod, Zeroable};

/// A texel's fields the refinement passes use, on either record they run on.
pub trait PassRecord: Pod + Send + Sync {
    /// The fused luminance (RGB) the passes refine.
    fn l_orig(&self) -> [f32; 3];
    fn set_l_orig(&mut self, l: [f32; 3]);
    /// The projection's weight (0: no photo observed the texel).
    fn weight(&self) -> f32;
    /// The last pass's statistics of the texel from its views' residuals `a`: `l_var`,
    /// `l_noise` and `disagree` (see [`super::apply_refinement`]).
    fn set_stats(&mut self, a: &Residual);
}

/// [`PassRecord`] for a record with the fields of that name.
macro_rules! pass_record {
    ($t:ty) => {
        impl PassRecord for $t {
            fn l_orig(&self) -> [f32; 3] {
                self.l_orig
            }
            fn set_l_orig(&mut self, l: [f32; 3]) {
                self.l_orig = l;
            }
            fn weight(&self) -> f32 {
                self.weight
            }
            fn set_stats(&mut self, a: &Residual) {
                self.l_var = fused_variance(a, self.weight);
                self.l_noise = photo_variance(a, self.weight);
                self.disagree = a.out;
            }
        }
    };
}

pass_record!(TexelState);
pass_record!(PassTexel);

/// The refinement's working record of a texel: the fields of [`TexelState`] it reads and
/// writes, with the same meanings.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct PassTexel {
    pub l_orig: [f32; 3],
    pub weight: f32,
    pub l_var: f32,
    pub l_noise: f32,
    pub disagree: f32,
}

impl PassTexel {
    /// The record of `s`.
    pub fn of(s: &TexelState) -> PassTexel {
        PassTexel {
            l_orig: s.l_orig,
            weight: s.weight,
            l_var: s.l_var,
            l_noise: s.l_noise,
            disagree: s.disagree,
        }
    }

    /// Its fields written back into `s` (the others left as they are).
    pub fn write_back(&self, s: &mut TexelState) {
        s.l_orig = self.l_orig;
        s.weight = self.weight;
        s.l_var = self.l_var;
        s.l_noise = self.l_noise;
        s.disagree = self.disagree;
    }
}

/// Every texel of `state` as a [`PassTexel`] into `work` (same layout), `window` tiles at a time.
pub fn copy_in(
    work: &mut TileStore<PassTexel>,
    state: &TileStore<TexelState>,
    window: usize,
) -> Result<()> {
    map_tiles(work, state, window, |_, st, w| {
        for (w, s) in w.iter_mut().zip(st) {
            *w = PassTexel::of(s);
        }
    })?;
    Ok(())
}

/// Every texel of `work` written back into `state` ([`PassTexel::write_back`]).
pub fn copy_back(
    state: &mut TileStore<TexelState>,
    work: &TileStore<PassTexel>,
    window: usize,
) -> Result<()> {
    map_tiles(state, work, window, |_, w, st| {
        for (s, w) in st.iter_mut().zip(w) {
            w.write_back(s);
        }
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record taken from a state and written back leaves the state as it was, and carries
    /// exactly the fields the passes use; the statistics are the same on both records.
    #[test]
    fn a_pass_texel_round_trips_and_keeps_the_same_statistics() {
        let s = TexelState {
            l_orig: [0.25, 0.5, 1.0],
            weight: 3.0,
            k_d: [0.1, 0.2, 0.3],
            e_d: [4.0; 3],
            l_var: 0.01,
            l_noise: 0.002,
            disagree: 1.0,
            flags: 7,
            ..Default::default()
        };
        let w = PassTexel::of(&s);
        assert_eq!((w.l_orig(), w.weight()), (s.l_orig, s.weight));
        let mut t = TexelState {
            l_orig: [9.0; 3],
            ..s
        };
        w.write_back(&mut t);
        assert_eq!(t, s);
        let a = Residual {
            wr2: 0.5,
            w2var: 0.3,
            views: 3.0,
            out: 1.0,
            ..Default::default()
        };
        let (mut s2, mut w2) = (s, w);
        s2.set_stats(&a);
        w2.set_stats(&a);
        let mut back = s;
        w2.write_back(&mut back);
        assert_eq!(back, s2);
        assert_ne!(s2.l_var, s.l_var, "the statistics changed");
    }
}
