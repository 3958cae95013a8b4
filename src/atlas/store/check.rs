//! Invariants of the tile stores between stages, in the spirit of obvhs's validation: the
//! pipeline runs them after every stage in debug builds (`cfg!(debug_assertions)`), so a stage
//! that writes a NaN, flags a texel inconsistently or loses a texel's geometry is caught where
//! it happens, not three stages later as a strange picture. A violation is an
//! [`Error::Internal`](crate::Error::Internal) naming the tile, the texel and the field.

use crate::atlas::store::TileStore;
use crate::atlas::store::{flags, TexelGeom, TexelState};
use crate::base::error::{Error, Result};

/// Every covered texel has finite geometry, unit normals, a positive area and a bin area of
/// the same order; every uncovered record is all zeros.
pub fn check_geometry(geom: &TileStore<TexelGeom>) -> Result<()> {
    for t in 0..geom.tile_count() {
        for (off, g) in geom.read_tile(t)?.iter().enumerate() {
            if let Err(what) = geometry_ok(g) {
                return Err(Error::internal(format!(
                    "geometry of texel {off} of tile {t}: {what}"
                )));
            }
        }
    }
    Ok(())
}

fn geometry_ok(g: &TexelGeom) -> std::result::Result<(), String> {
    if !g.covered() {
        return match *g == TexelGeom::default() {
            true => Ok(()),
            false => Err("uncovered texel with a non-empty record".into()),
        };
    }
    if g.flags != flags::COVERED {
        return Err(format!("unknown flags {:#x}", g.flags));
    }
    if !g.p().is_finite() {
        return Err(format!("position {}", g.p()));
    }
    for (name, n) in [("normal", g.n()), ("geometric normal", g.ng())] {
        let off = (n.length() - 1.0).abs();
        if off.is_nan() || off >= 1e-3 {
            return Err(format!("{name} {n} is not unit length"));
        }
    }
    if !(g.area.is_finite() && g.area > 0.0) {
        return Err(format!("area {}", g.area));
    }
    // The bin is measured with sub-samples over the chart, which on a curved mesh cross
    // triangles of other texel areas (uvunwrap bounds that distortion at 1.25x per chart), so
    // the bin may exceed the center triangle's texel area a little, never by several times.
    if !(g.bin_area >= 0.0 && g.bin_area <= g.area * 2.0) {
        return Err(format!("bin area {} for a texel of {}", g.bin_area, g.area));
    }
    Ok(())
}

/// Every value is finite and non-negative; flags are known; `OBSERVED` texels are covered
/// and have weight, `FILLED` ones are covered and not observed; uncovered texels carry no
/// flags and no observation.
pub fn check_state(state: &TileStore<TexelState>, geom: &TileStore<TexelGeom>) -> Result<()> {
    for t in 0..state.tile_count() {
        let (s, g) = (state.read_tile(t)?, geom.read_tile(t)?);
        for (off, (s, g)) in s.iter().zip(&g).enumerate() {
            if let Err(what) = state_ok(s, g.covered()) {
                return Err(Error::internal(format!(
                    "state of texel {off} of tile {t}: {what}"
                )));
            }
        }
    }
    Ok(())
}

fn state_ok(s: &TexelState, covered: bool) -> std::result::Result<(), String> {
    let fields: [(&str, &[f32]); 12] = [
        ("l_orig", &s.l_orig),
        ("weight", std::slice::from_ref(&s.weight)),
        ("e_d", &s.e_d),
        ("e_i", &s.e_i),
        ("k_d", &s.k_d),
        ("error", std::slice::from_ref(&s.error)),
        ("accum", &s.accum),
        ("l_var", std::slice::from_ref(&s.l_var)),
        ("e_var", std::slice::from_ref(&s.e_var)),
        ("disagree", std::slice::from_ref(&s.disagree)),
        ("l_noise", std::slice::from_ref(&s.l_noise)),
        ("ed_var", std::slice::from_ref(&s.ed_var)),
    ];
    for (name, v) in fields {
        if v.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err(format!("{name} = {v:?}"));
        }
    }
    let known = flags::COVERED | flags::OBSERVED | flags::FILLED;
    if s.flags & !known != 0 {
        return Err(format!("unknown flags {:#x}", s.flags));
    }
    let observed = s.flags & flags::OBSERVED != 0;
    let filled = s.flags & flags::FILLED != 0;
    if (observed || filled) && !covered {
        return Err("flagged observed or filled but not covered".into());
    }
    if observed != (s.weight > 0.0) {
        return Err(format!("observed = {observed} with weight {}", s.weight));
    }
    if observed && filled {
        return Err("both observed and filled".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn covered() -> TexelGeom {
        TexelGeom {
            position: [1.0, 2.0, 3.0],
            normal: [0.0, 1.0, 0.0],
            geo_normal: [0.0, 0.0, 1.0],
            area: 0.01,
            bin_area: 0.005,
            tri: 3,
            flags: flags::COVERED,
        }
    }

    #[test]
    fn good_records_pass_and_each_broken_invariant_is_named() {
        assert!(geometry_ok(&covered()).is_ok());
        assert!(geometry_ok(&TexelGeom::default()).is_ok());
        let mut g = covered();
        g.normal = [0.0, 2.0, 0.0];
        assert!(geometry_ok(&g).unwrap_err().contains("normal"));
        let mut g = covered();
        g.bin_area = 0.05;
        assert!(geometry_ok(&g).unwrap_err().contains("bin area"));
        let g = TexelGeom {
            area: 1.0,
            ..Default::default()
        };
        assert!(geometry_ok(&g).unwrap_err().contains("uncovered"));

        let good = TexelState {
            l_orig: [0.1; 3],
            weight: 2.0,
            flags: flags::OBSERVED,
            ..Default::default()
        };
        assert!(state_ok(&good, true).is_ok());
        assert!(state_ok(&TexelState::default(), false).is_ok());
        let mut s = good;
        s.e_i[1] = f32::NAN;
        assert!(state_ok(&s, true).unwrap_err().contains("e_i"));
        let mut s = good;
        s.l_var = -1.0;
        assert!(state_ok(&s, true).unwrap_err().contains("l_var"));
        let mut s = good;
        s.k_d[0] = -0.5;
        assert!(state_ok(&s, true).unwrap_err().contains("k_d"));
        assert!(state_ok(&good, false).unwrap_err().contains("not covered"));
        let mut s = good;
        s.weight = 0.0;
        assert!(state_ok(&s, true).unwrap_err().contains("weight"));
        let mut s = good;
        s.flags |= flags::FILLED;
        assert!(state_ok(&s, true).unwrap_err().contains("both"));
    }

    #[test]
    fn a_nan_in_a_store_is_found_with_its_tile_and_texel() {
        let dir = tempfile::tempdir().unwrap();
        let mut state =
            TileStore::create(dir.path().join("s"), 2, 4, TexelState::default()).unwrap();
        let geom = TileStore::create(dir.path().join("g"), 2, 4, TexelGeom::default()).unwrap();
        check_state(&state, &geom).unwrap();
        check_geometry(&geom).unwrap();
        let mut t = state.read_tile(1).unwrap();
        t[2].e_d[0] = f32::INFINITY;
        state.write_tile(1, &t).unwrap();
        let e = check_state(&state, &geom).unwrap_err();
        assert!(matches!(e, Error::Internal(_)));
        assert!(e.to_string().contains("texel 2 of tile 1: e_d"), "{e}");
    }
}
