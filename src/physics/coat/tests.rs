//! The coat's factors against closed forms and brute-force integration.

use super::*;
use crate::scene::material::{diffuse_fresnel_inside, KnownBsdf};

fn plastic(eta: f32, rough: Option<Rough>) -> Coat {
    Coat::of(&KnownBsdf::plastic(
        eta,
        Vec3::splat(0.5),
        Vec3::ONE,
        rough,
        false,
    ))
    .unwrap()
}

/// A smooth coat: `t = 1 - F`, `T_o = (1 - F) / (eta^2 (1 - F_dr,int))`, and the mean
/// transmittance `1 - 2 integral F mu` by brute-force Monte Carlo over the hemisphere.
#[test]
fn smooth_coat_factors_are_fresnel_s() {
    let c = plastic(1.49, None);
    let fdr = diffuse_fresnel_inside(1.49);
    for cos in [1.0f32, 0.8, 0.5, 0.2, 0.05] {
        let f = fresnel_dielectric(cos, 1.49);
        assert!((c.transmittance(cos) - (1.0 - f)).abs() < 1e-6);
        let want = (1.0 - f) / (1.49 * 1.49 * (1.0 - fdr));
        assert!((c.base_out(cos) - want).abs() < 1e-6, "{cos}");
    }
    let mut rng = Rng::new(3, 0, 0, 0);
    let n = 200_000;
    let mc: f64 = (0..n)
        .map(|_| {
            // cosine-weighted: mu = sqrt(u)
            let mu = rng.f32().sqrt();
            fresnel_dielectric(mu, 1.49) as f64
        })
        .sum::<f64>()
        / n as f64;
    assert!(((1.0 - mc) as f32 - c.mean_transmittance()).abs() < 2e-3);
    // A white base under a uniform sky reflects (diffuse part) t_mean^2 / (eta^2 (1 - F_dr)),
    // which with the coat's own reflection conserves energy.
    let diffuse = c.mean_transmittance() * c.mean_transmittance() / (1.49 * 1.49 * (1.0 - fdr));
    assert!(
        diffuse + (1.0 - c.mean_transmittance()) <= 1.0 + 1e-3,
        "{diffuse}"
    );
    // the smooth reflection: one mirror direction weighted by F
    let wi = Vec3::new(0.6, 0.0, 0.8);
    let lobes = c.reflection(wi, Vec3::Z, &mut Rng::new(1, 0, 0, 0));
    assert_eq!(lobes.len(), 1);
    assert!((lobes[0].0 - Vec3::new(-0.6, 0.0, 0.8)).length() < 1e-6);
    assert!((lobes[0].1.x - fresnel_dielectric(0.8, 1.49)).abs() < 1e-6);
}

/// A rough coat: its transmittance and the albedo of its reflection lobe (the lobe samples'
/// weights, averaged over many pixels, integrate that albedo) add up to a little under 1 (the
/// microfacets shadow some light), by less at steeper angles, and both tend to the smooth
/// coat's as `alpha -> 0`.
#[test]
fn rough_coat_transmittance_and_reflection_add_up_to_nearly_one() {
    let r = Rough {
        alpha: 0.2,
        ggx: false,
    };
    let c = plastic(1.5, Some(r));
    for mu in [0.95f32, 0.6, 0.3] {
        let wi = Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
        let keys = 4000;
        let albedo: f32 = (0..keys)
            .map(|k| {
                let l = c.reflection(wi, Vec3::Z, &mut Rng::new(5, 0, 0, k));
                l.iter().map(|s| s.1.x).sum::<f32>()
            })
            .sum::<f32>()
            / keys as f32;
        let lost = 1.0 - c.transmittance(mu) - albedo;
        let most = if mu > 0.5 { 0.01 } else { 0.05 };
        let t = c.transmittance(mu);
        assert!((-0.005..most).contains(&lost), "{mu}: {albedo} + {t}");
    }
    let smooth = plastic(1.5, None);
    let sharp = plastic(
        1.5,
        Some(Rough {
            alpha: 0.005,
            ggx: true,
        }),
    );
    for mu in [0.9f32, 0.5, 0.25] {
        let d = (sharp.transmittance(mu) - smooth.transmittance(mu)).abs();
        assert!(d < 0.01, "{mu}: {d}");
    }
    // Mitsuba's rough `R_int` is a plain mean over its 64 cosines (endpoints included), about
    // 1.6% under the smooth coat's integral, so the two plastics' `T_o` differ by about 2.5%
    let r = sharp.base_out(0.7) / smooth.base_out(0.7);
    assert!((0.96..0.99).contains(&r), "{r}");
}

/// Only plastics with `nonlinear = false` (alone or picked always by a blend) are coats.
#[test]
fn only_linear_plastics_are_coats() {
    let p = KnownBsdf::plastic(1.5, Vec3::splat(0.5), Vec3::ONE, None, false);
    assert!(Coat::of(&p).is_some());
    let nl = KnownBsdf::plastic(1.5, Vec3::splat(0.5), Vec3::ONE, None, true);
    assert!(Coat::of(&nl).is_none());
    let blend = |w: f32| KnownBsdf::Blend {
        weight: w,
        a: Box::new(p.clone()),
        b: Box::new(KnownBsdf::Null),
    };
    assert!(Coat::of(&blend(0.0)).is_some());
    assert!(Coat::of(&blend(0.3)).is_none());
    assert!(Coat::of(&KnownBsdf::Diffuse(Vec3::ONE)).is_none());
}

/// The base's part of the BSDF against Mitsuba 3.9.1's own (`scalar_rgb`, `bsdf.eval` of a
/// `plastic` and a GGX `roughplastic` of `alpha = 0.15`, `int_ior = 1.5`, a white base and no
/// specular part, lit along the normal and seen at cosine `mu`, times `pi / mu`):
/// `t(1) t(mu) / (eta^2 (1 - R_int))`. The rough coat's tables are integrated differently
/// (a grid of normals here, quadrature there), within 2% at grazing angles.
#[test]
fn the_base_s_factors_match_mitsuba_s() {
    let mitsuba = [
        (None, [1.015947, 1.0044, 0.918075, 0.699673], [0.002; 4]),
        (
            Some(Rough {
                alpha: 0.15,
                ggx: true,
            }),
            [0.852647, 0.837876, 0.770931, 0.663064],
            [0.003, 0.006, 0.012, 0.025],
        ),
    ];
    for (rough, want, tol) in mitsuba {
        let c = plastic(1.5, rough);
        for (k, mu) in [1.0f32, 0.7, 0.4, 0.2].into_iter().enumerate() {
            let got = c.transmittance(1.0) * c.base_out(mu);
            let rel = (got / want[k] - 1.0).abs();
            assert!(rel < tol[k], "{rough:?} at {mu}: {got} vs {}", want[k]);
        }
    }
}
