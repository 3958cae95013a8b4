//! Known (not reconstructed) materials: what the light transport needs of Mitsuba's
//! non-diffuse BSDFs, with the index-of-refraction and metal presets Mitsuba names, settled
//! at load to RGB and relative IORs. Sampling them is `physics::bsdf_sampling`'s job.

use super::Rgb;
use glam::Vec3;

/// A known (not reconstructed) material, as the light transport uses it.
#[derive(Debug, Clone, PartialEq)]
pub enum KnownBsdf {
    /// Lambertian of known reflectance (a `reconstruct = false` shape, or the diffuse part
    /// of a blend).
    Diffuse(Rgb),
    /// Metal: complex index of refraction `eta + i k` relative to the outside, a specular
    /// tint, a microfacet roughness (`None`: smooth).
    Conductor {
        eta: Rgb,
        k: Rgb,
        tint: Rgb,
        rough: Option<Rough>,
    },
    /// Glass: index of refraction inside over outside; tints of the reflected and the
    /// transmitted light. `thin`: a thin sheet (light passes straight through).
    Dielectric {
        eta: f32,
        reflect: Rgb,
        transmit: Rgb,
        rough: Option<Rough>,
        thin: bool,
    },
    /// A dielectric coat of index `eta` over a diffuse base (`plastic`, `roughplastic`).
    /// Made by [`KnownBsdf::plastic`], which settles `fdr_int` once.
    Plastic {
        eta: f32,
        diffuse: Rgb,
        specular: Rgb,
        rough: Option<Rough>,
        nonlinear: bool,
        /// [`diffuse_fresnel_inside`]`(eta)`, kept so sampling does not integrate it per path.
        fdr_int: f32,
    },
    /// `blendbsdf`: `b` with probability `weight`, else `a`.
    Blend {
        weight: f32,
        a: Box<KnownBsdf>,
        b: Box<KnownBsdf>,
    },
    /// `mask`: the surface `inner` with probability `opacity`, else light passes unchanged.
    Mask { opacity: f32, inner: Box<KnownBsdf> },
    /// `null`: invisible to light.
    Null,
}

impl KnownBsdf {
    /// A plastic of coat index `eta` (inside over outside) over a `diffuse` base.
    pub fn plastic(
        eta: f32,
        diffuse: Rgb,
        specular: Rgb,
        rough: Option<Rough>,
        nonlinear: bool,
    ) -> Self {
        KnownBsdf::Plastic {
            eta,
            diffuse,
            specular,
            rough,
            nonlinear,
            fdr_int: diffuse_fresnel_inside(eta),
        }
    }
}

impl KnownBsdf {
    /// The plastic whose diffuse base kdmap can reconstruct under its coat: a `plastic` or
    /// `roughplastic` with `nonlinear = false`, also inside blends that pick one side always
    /// (a `principled` with `metallic = 0` and `spec_trans = 0`).
    pub fn coat(&self) -> Option<&KnownBsdf> {
        match self {
            KnownBsdf::Plastic {
                nonlinear: false, ..
            } => Some(self),
            KnownBsdf::Blend { weight, a, .. } if *weight == 0.0 => a.coat(),
            KnownBsdf::Blend { weight, b, .. } if *weight == 1.0 => b.coat(),
            _ => None,
        }
    }
}

/// A microfacet roughness (isotropic: Mitsuba's `alpha`, or the mean of `alpha_u/v`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rough {
    pub alpha: f32,
    /// GGX; else Beckmann (Mitsuba's default).
    pub ggx: bool,
}

/// A known material with the Mitsuba plugin it came from (for reports).
#[derive(Debug, Clone, PartialEq)]
pub struct KnownMaterial {
    /// `conductor`, `dielectric`, ..., or `diffuse (known)` for a run-config reflectance.
    pub plugin: String,
    pub bsdf: KnownBsdf,
}

#[cfg(test)]
impl KnownMaterial {
    /// Mitsuba's `conductor` with `material = "none"`: a perfect mirror (Fresnel factor 1).
    pub fn perfect_mirror() -> Self {
        KnownMaterial {
            plugin: "conductor".into(),
            bsdf: KnownBsdf::Conductor {
                eta: Vec3::ZERO,
                k: Vec3::ONE,
                tint: Vec3::ONE,
                rough: None,
            },
        }
    }
}

/// Mitsuba's named indices of refraction (`src/core/..` `lookup_ior`), as it spells them.
pub const IOR_PRESETS: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.3330),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.5750),
    ("diamond", 2.419),
];

/// Conductor presets `(name, eta, k)` in linear RGB: the common metals of Mitsuba's list,
/// their measured spectra reduced to RGB (the values PBRT and Mitsuba 0.6's RGB mode use).
/// Mitsuba's other presets load as the ideal mirror `none` (a documented approximation).
pub const METAL_PRESETS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    ("Ag", [0.155, 0.117, 0.138], [4.828, 3.122, 2.147]),
    ("Al", [1.657, 0.880, 0.521], [9.224, 6.270, 4.837]),
    ("Au", [0.143, 0.374, 1.442], [3.983, 2.385, 1.603]),
    ("Cu", [0.200, 0.924, 1.102], [3.912, 2.452, 2.142]),
    ("Cr", [4.368, 2.910, 1.654], [5.195, 4.231, 3.754]),
];

/// Mitsuba's default dielectric `int_ior` (bk7) and every `ext_ior` default (air).
pub const BK7: f32 = 1.5046;
pub const AIR: f32 = 1.000277;
/// `plastic`'s default `int_ior` (polypropylene).
pub const POLYPROPYLENE: f32 = 1.49;

/// The index of refraction Mitsuba's preset `name` stands for.
pub fn ior_preset(name: &str) -> Option<f32> {
    let n = name.trim().to_ascii_lowercase();
    IOR_PRESETS.iter().find(|p| p.0 == n).map(|p| p.1)
}

/// `(eta, k)` of conductor preset `name`: `Some(exact)` for a listed one, `None` otherwise.
pub fn metal_preset(name: &str) -> Option<(Rgb, Rgb)> {
    METAL_PRESETS
        .iter()
        .find(|p| p.0 == name.trim())
        .map(|p| (Vec3::from_array(p.1), Vec3::from_array(p.2)))
}

/// Unpolarized Fresnel reflectance of a dielectric interface for `cos_i` (> 0: arriving
/// from the outside, < 0: from the inside) and relative index `eta` (inside over outside);
/// 1 under total internal reflection.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (c, eta) = match cos_i >= 0.0 {
        true => (cos_i.min(1.0), eta),
        false => ((-cos_i).min(1.0), 1.0 / eta),
    };
    if eta == 1.0 {
        return 0.0;
    }
    let sin2_t = (1.0 - c * c) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let ct = (1.0 - sin2_t).sqrt();
    let rs = (c - eta * ct) / (c + eta * ct);
    let rp = (eta * c - ct) / (eta * c + ct);
    0.5 * (rs * rs + rp * rp)
}

/// Unpolarized Fresnel reflectance of a conductor of complex index `eta + i k` for `cos_i`
/// (Mitsuba's `fresnel_conductor`), per channel.
pub fn fresnel_conductor(cos_i: f32, eta: Rgb, k: Rgb) -> Rgb {
    let c = cos_i.clamp(0.0, 1.0);
    let (c2, s2) = (c * c, 1.0 - c * c);
    let one = |eta: f32, k: f32| {
        let (e2, k2) = (eta * eta, k * k);
        let t0 = e2 - k2 - s2;
        let a2pb2 = (t0 * t0 + 4.0 * e2 * k2).max(0.0).sqrt();
        let a = (0.5 * (a2pb2 + t0)).max(0.0).sqrt();
        let t1 = a2pb2 + c2;
        let t2 = 2.0 * c * a;
        let rs = (t1 - t2) / (t1 + t2);
        let t3 = c2 * a2pb2 + s2 * s2;
        let t4 = t2 * s2;
        let rp = rs * (t3 - t4) / (t3 + t4);
        let f = 0.5 * (rs + rp);
        if f.is_finite() {
            f.clamp(0.0, 1.0)
        } else {
            1.0
        }
    };
    Vec3::new(one(eta.x, k.x), one(eta.y, k.y), one(eta.z, k.z))
}

/// The diffuse Fresnel reflectance seen from inside a medium of relative index `eta`: the
/// cosine-weighted hemispherical mean of [`fresnel_dielectric`] from the inside, by
/// quadrature (what Mitsuba's `plastic` calls `m_fdr_int`).
pub fn diffuse_fresnel_inside(eta: f32) -> f32 {
    const N: usize = 256;
    (0..N)
        .map(|i| {
            let mu = (i as f32 + 0.5) / N as f32;
            fresnel_dielectric(-mu, eta) * 2.0 * mu / N as f32
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_has_its_closed_forms() {
        // normal incidence: ((n - 1) / (n + 1))^2, both ways
        let r0 = (0.5f32 / 2.5).powi(2);
        assert!((fresnel_dielectric(1.0, 1.5) - r0).abs() < 1e-6);
        assert!((fresnel_dielectric(-1.0, 1.5) - r0).abs() < 1e-6);
        // grazing: 1; total internal reflection beyond the critical angle
        assert!((fresnel_dielectric(1e-6, 1.5) - 1.0).abs() < 1e-3);
        let crit = (1.0f32 - (1.0 / 1.5f32).powi(2)).sqrt();
        assert_eq!(fresnel_dielectric(-(crit - 0.01), 1.5), 1.0);
        assert!(fresnel_dielectric(-(crit + 0.01), 1.5) < 1.0);
        // Brewster's angle: p-polarized part vanishes, so F = rs^2 / 2 there
        let tb = 1.5f32.atan();
        let f = fresnel_dielectric(tb.cos(), 1.5);
        let ct = (1.0 - tb.sin().powi(2) / 2.25).sqrt();
        let rs = (tb.cos() - 1.5 * ct) / (tb.cos() + 1.5 * ct);
        assert!((f - 0.5 * rs * rs).abs() < 1e-6);
        // a conductor with k = 0 is a dielectric; normal incidence ((n-1)^2+k^2)/((n+1)^2+k^2)
        for c in [1.0f32, 0.7, 0.3] {
            let f = fresnel_conductor(c, Vec3::splat(1.5), Vec3::ZERO).x;
            assert!((f - fresnel_dielectric(c, 1.5)).abs() < 1e-5, "{c}");
        }
        let (n, k) = (0.2f32, 3.9f32);
        let f = fresnel_conductor(1.0, Vec3::splat(n), Vec3::splat(k)).x;
        let want = ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k);
        assert!((f - want).abs() < 1e-5);
        // the ideal mirror
        let f = fresnel_conductor(0.4, Vec3::ZERO, Vec3::ONE);
        assert!((f - Vec3::ONE).abs().max_element() < 1e-6);
    }

    /// The inside diffuse reflectance of glass against the classic fit for eta > 1
    /// (Egan and Hilgeman: -1.4399/eta^2 + 0.7099/eta + 0.6681 + 0.0636 eta).
    #[test]
    fn diffuse_fresnel_inside_matches_the_fit() {
        for eta in [1.33f32, 1.49, 1.7] {
            let fit = -1.4399 / (eta * eta) + 0.7099 / eta + 0.6681 + 0.0636 * eta;
            let q = diffuse_fresnel_inside(eta);
            assert!((q - fit).abs() < 0.01, "{eta}: {q} vs {fit}");
        }
    }

    #[test]
    fn presets_resolve() {
        assert_eq!(ior_preset("BK7"), Some(BK7));
        assert_eq!(ior_preset("acrylic glass"), Some(1.49));
        assert_eq!(ior_preset("unobtainium"), None);
        assert!(metal_preset("Au").is_some());
        assert!(metal_preset("Xx").is_none());
    }
}
