//! Mitsuba 3's non-diffuse BSDFs read as known materials ([`KnownBsdf`]): `conductor`,
//! `roughconductor`, `dielectric`, `roughdielectric`, `thindielectric`, `plastic`,
//! `roughplastic`, `principled`, `principledthin`, `blendbsdf`, `mask`, `null`, and
//! `bumpmap`/`normalmap` (their inner bsdf; the bump is ignored). Property names and defaults
//! as in Mitsuba 3.9's `src/bsdfs/*.cpp`.
//!
//! Approximations, documented in docs/guide.md ("Known materials"): a parameter given as a
//! texture takes the plugin's default (known materials are uniform here); anisotropic roughness
//! takes the mean of `alpha_u` and `alpha_v`; conductor presets other than those of
//! [`METAL_PRESETS`] are an ideal mirror; `principled` becomes a blend of a rough mirror tinted
//! by `base_color` (`metallic`), a rough glass (`spec_trans`) and a rough plastic over
//! `base_color`, with `alpha = roughness^2`; sheen, clearcoat and specular tint are dropped.

use super::{Bsdf, Parser, Props};
use crate::scene::material::{self, KnownBsdf, KnownMaterial, Rough, AIR, BK7, POLYPROPYLENE};
use crate::scene::{ReflectanceSpec, Rgb, Sides};
use crate::Result;
use glam::Vec3;
use roxmltree::Node;

/// The bsdf plugins kdmap models as known materials.
pub const KNOWN_BSDFS: &[&str] = &[
    "conductor",
    "roughconductor",
    "dielectric",
    "roughdielectric",
    "thindielectric",
    "plastic",
    "roughplastic",
    "principled",
    "principledthin",
    "blendbsdf",
    "mask",
    "null",
    "bumpmap",
    "normalmap",
];

impl<'a, 'i> Parser<'a, 'i> {
    /// A known-material bsdf `kind` at `node`: its nested bsdfs parsed (ids registered),
    /// every property read or read past.
    pub(super) fn known_bsdf(&mut self, node: Node<'a, 'i>, kind: &str) -> Result<Bsdf> {
        let mut props = self.props(node)?;
        let mut inner = Vec::new();
        for o in std::mem::take(&mut props.objects) {
            match o.tag_name().name() {
                "bsdf" => inner.push((self.bsdf(o)?, o)),
                "ref" if self.is_bsdf_ref(o) => inner.push((self.bsdf_ref(o)?, o)),
                "texture" => {
                    self.texture_kind(o)?;
                    props.objects.push(o);
                }
                "ref" => {
                    self.check_attrs(o, &["id", "name"])?;
                    props.objects.push(o);
                }
                other => {
                    return Err(self.err(o, format!("unsupported element <{other}> in a bsdf")))
                }
            }
        }
        let bsdf = match kind {
            "conductor" | "roughconductor" => {
                self.conductor(&mut props, kind == "roughconductor", node)?
            }
            "dielectric" | "roughdielectric" | "thindielectric" => {
                self.dielectric(&mut props, kind)?
            }
            "plastic" | "roughplastic" => self.plastic(&mut props, kind == "roughplastic")?,
            "principled" | "principledthin" => self.principled(&mut props, kind)?,
            "null" => KnownBsdf::Null,
            _ => self.wrapper(&mut props, kind, node, &inner)?,
        };
        let sides = match &bsdf {
            KnownBsdf::Dielectric { .. } | KnownBsdf::Null => Sides::Both,
            _ => Sides::Front,
        };
        Ok(Bsdf {
            sides,
            reflectance: self.coat_base(node, kind, &bsdf),
            unsupported: None,
            known: Some(KnownMaterial {
                plugin: kind.to_string(),
                bsdf,
            }),
        })
    }

    /// The base a coated material states (see [`KnownBsdf::coat`]): its `diffuse_reflectance`
    /// (a principled's `base_color`), Mitsuba's 0.5 when absent. For the truth reader only.
    fn coat_base(
        &mut self,
        node: Node<'a, 'i>,
        kind: &str,
        b: &KnownBsdf,
    ) -> Option<ReflectanceSpec> {
        b.coat()?;
        let name = match kind {
            "plastic" | "roughplastic" => "diffuse_reflectance",
            "principled" | "principledthin" => "base_color",
            _ => return None,
        };
        let stated = Self::elements(node).any(|c| c.attribute("name") == Some(name));
        match stated {
            true => self.stated(node, name),
            false => Some(ReflectanceSpec::Constant(Vec3::splat(0.5))),
        }
    }

    fn is_bsdf_ref(&self, o: Node) -> bool {
        o.attribute("id")
            .is_some_and(|id| self.bsdfs.contains_key(id))
    }

    /// `blendbsdf`, `mask`, `bumpmap`, `normalmap`: built around their nested bsdfs.
    fn wrapper(
        &self,
        props: &mut Props<'a, 'i>,
        kind: &str,
        node: Node<'a, 'i>,
        inner: &[(Bsdf, Node<'a, 'i>)],
    ) -> Result<KnownBsdf> {
        let want = if kind == "blendbsdf" { 2 } else { 1 };
        if inner.len() != want {
            return Err(self.err(
                node,
                format!("{kind} needs {want} nested bsdf(s), found {}", inner.len()),
            ));
        }
        let mut parts = Vec::new();
        for (b, at) in inner {
            parts.push(self.as_known(b, *at)?);
        }
        let mut next = || Box::new(parts.pop().unwrap_or(KnownBsdf::Null));
        Ok(match kind {
            "blendbsdf" => {
                let weight = self.param_f(props, "weight", 0.5)?.clamp(0.0, 1.0);
                let b = next();
                let a = next();
                KnownBsdf::Blend { weight, a, b }
            }
            "mask" => KnownBsdf::Mask {
                opacity: self.param_f(props, "opacity", 0.5)?.clamp(0.0, 1.0),
                inner: next(),
            },
            // bumpmap / normalmap: the bump is ignored
            _ => {
                props.take("scale");
                props.take("flip_invalid_normals");
                *next()
            }
        })
    }

    /// A nested bsdf as a known material: a diffuse one by the reflectance it states (a
    /// texture: mid grey, documented), a non-diffuse one as read; unsupported ones refused.
    fn as_known(&self, b: &Bsdf, at: Node) -> Result<KnownBsdf> {
        if let Some(kind) = &b.unsupported {
            return Err(self.err(at, format!("bsdf '{kind}' is not supported yet")));
        }
        Ok(match (&b.known, &b.reflectance) {
            (Some(k), _) => k.bsdf.clone(),
            (None, Some(ReflectanceSpec::Constant(c))) => KnownBsdf::Diffuse(*c),
            (None, _) => KnownBsdf::Diffuse(Vec3::splat(0.5)),
        })
    }

    fn conductor(
        &mut self,
        props: &mut Props<'a, 'i>,
        rough: bool,
        node: Node,
    ) -> Result<KnownBsdf> {
        let preset = match props.take("material") {
            Some(n) => self.string_of(n)?,
            None => "none".to_string(),
        };
        let (mut eta, mut k) = material::metal_preset(&preset).unwrap_or((Vec3::ZERO, Vec3::ONE));
        if let Some(e) = self.param_rgb(props, "eta")? {
            eta = e;
        }
        if let Some(kk) = self.param_rgb(props, "k")? {
            k = kk;
        }
        if (props.peek("eta").is_some() || props.peek("k").is_some())
            && props.peek("material").is_some()
        {
            return Err(self.err(node, "give either 'material' or 'eta'/'k', not both"));
        }
        let tint = self
            .param_rgb(props, "specular_reflectance")?
            .unwrap_or(Vec3::ONE);
        Ok(KnownBsdf::Conductor {
            eta,
            k,
            tint,
            rough: if rough {
                Some(self.roughness(props)?)
            } else {
                None
            },
        })
    }

    fn dielectric(&mut self, props: &mut Props<'a, 'i>, kind: &str) -> Result<KnownBsdf> {
        let int = self.ior(props, "int_ior", BK7)?;
        let ext = self.ior(props, "ext_ior", AIR)?;
        let reflect = self
            .param_rgb(props, "specular_reflectance")?
            .unwrap_or(Vec3::ONE);
        let transmit = self
            .param_rgb(props, "specular_transmittance")?
            .unwrap_or(Vec3::ONE);
        let rough = match kind {
            "roughdielectric" => Some(self.roughness(props)?),
            _ => None,
        };
        Ok(KnownBsdf::Dielectric {
            eta: int / ext,
            reflect,
            transmit,
            rough,
            thin: kind == "thindielectric",
        })
    }

    fn plastic(&mut self, props: &mut Props<'a, 'i>, rough: bool) -> Result<KnownBsdf> {
        let int = self.ior(props, "int_ior", POLYPROPYLENE)?;
        let ext = self.ior(props, "ext_ior", AIR)?;
        let diffuse = self
            .param_rgb(props, "diffuse_reflectance")?
            .unwrap_or(Vec3::splat(0.5));
        let specular = self
            .param_rgb(props, "specular_reflectance")?
            .unwrap_or(Vec3::ONE);
        let nonlinear = match props.take("nonlinear") {
            Some(n) => self.bool_of(n)?,
            None => false,
        };
        let rough = match rough {
            true => Some(self.roughness(props)?),
            false => None,
        };
        Ok(KnownBsdf::plastic(
            int / ext,
            diffuse,
            specular,
            rough,
            nonlinear,
        ))
    }

    /// `principled` / `principledthin` as a blend (see the module doc).
    fn principled(&mut self, props: &mut Props<'a, 'i>, kind: &str) -> Result<KnownBsdf> {
        let base = self
            .param_rgb(props, "base_color")?
            .unwrap_or(Vec3::splat(0.5));
        let r = self.param_f(props, "roughness", 0.5)?.clamp(0.0, 1.0);
        let metallic = self.param_f(props, "metallic", 0.0)?.clamp(0.0, 1.0);
        let trans = self.param_f(props, "spec_trans", 0.0)?.clamp(0.0, 1.0);
        let eta = match props.peek("eta") {
            Some(_) => self.param_f(props, "eta", 1.5)?,
            None => {
                // Mitsuba derives eta from `specular` when eta is absent.
                let s = self.param_f(props, "specular", 0.5)?.clamp(0.0, 0.999);
                2.0 / (1.0 - (0.08 * s).sqrt()) - 1.0
            }
        };
        let rough = (r > 0.0).then_some(Rough {
            alpha: (r * r).max(1e-3),
            ggx: true,
        });
        let plastic = KnownBsdf::plastic(eta, base, Vec3::ONE, rough, false);
        let glass = KnownBsdf::Dielectric {
            eta,
            reflect: Vec3::ONE,
            transmit: base,
            rough,
            thin: kind == "principledthin",
        };
        let metal = KnownBsdf::Conductor {
            eta: Vec3::ZERO,
            k: Vec3::ONE,
            tint: base,
            rough,
        };
        Ok(KnownBsdf::Blend {
            weight: metallic,
            a: Box::new(KnownBsdf::Blend {
                weight: trans,
                a: Box::new(plastic),
                b: Box::new(glass),
            }),
            b: Box::new(metal),
        })
    }

    /// `alpha` (or the mean of `alpha_u`, `alpha_v`; Mitsuba's default 0.1) and `distribution`.
    fn roughness(&self, props: &mut Props<'a, 'i>) -> Result<Rough> {
        let ggx = match props.take("distribution") {
            Some(n) => match self.string_of(n)?.as_str() {
                "beckmann" => false,
                "ggx" => true,
                other => {
                    return Err(self.err(
                        n,
                        format!("invalid distribution '{other}' (beckmann or ggx)"),
                    ))
                }
            },
            None => false,
        };
        props.take("sample_visible");
        let alpha = match props.peek("alpha_u").or(props.peek("alpha_v")) {
            Some(_) => {
                0.5 * (self.param_f(props, "alpha_u", 0.1)?
                    + self.param_f(props, "alpha_v", 0.1)?)
            }
            None => self.param_f(props, "alpha", 0.1)?,
        };
        Ok(Rough {
            alpha: alpha.max(1e-4),
            ggx,
        })
    }

    /// An index of refraction: a number or one of Mitsuba's preset names.
    fn ior(&self, props: &mut Props<'a, 'i>, name: &str, default: f32) -> Result<f32> {
        let Some(n) = props.take(name) else {
            return Ok(default);
        };
        let v = match n.tag_name().name() {
            "string" => {
                let s = self.string_of(n)?;
                material::ior_preset(&s)
                    .ok_or_else(|| self.err(n, format!("unknown index of refraction '{s}'")))?
            }
            _ => self.float_of(n)? as f32,
        };
        match v.is_finite() && v > 0.0 {
            true => Ok(v),
            false => Err(self.err(n, format!("'{name}' must be positive"))),
        }
    }

    /// An RGB parameter: `Some` when given as a value, `None` when absent or a texture
    /// (which takes the plugin's default; see the module doc).
    fn param_rgb(&self, props: &mut Props<'a, 'i>, name: &str) -> Result<Option<Rgb>> {
        match props.take(name) {
            Some(n) => {
                let c = self.color_of(n)?.as_vec3();
                match c.is_finite() && c.min_element() >= 0.0 {
                    true => Ok(Some(c)),
                    false => Err(self.err(n, format!("'{name}' must be finite and non-negative"))),
                }
            }
            None => Ok(None),
        }
    }

    /// A scalar parameter, `default` when absent or a texture.
    fn param_f(&self, props: &mut Props<'a, 'i>, name: &str, default: f32) -> Result<f32> {
        match props.take(name) {
            Some(n) => {
                let v = self.float_of(n)? as f32;
                match v.is_finite() {
                    true => Ok(v),
                    false => Err(self.err(n, format!("'{name}' must be finite"))),
                }
            }
            None => Ok(default),
        }
    }
}
