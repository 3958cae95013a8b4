//! `scene.xml`: the recovered scene as a Mitsuba 3 file that loads as it is, the starting
//! point for a differentiable refinement. Every reconstructed shape keeps its id and becomes
//! an `obj` (`meshes/<id>.obj`, world space, atlas UVs) with a `diffuse` bsdf whose
//! reflectance is the recovered albedo (`textures/<id>_albedo.exr`, `raw="true"` so the
//! linear values are used as they are), wrapped in `twosided` where the input reflected on
//! both sides (a coated shape: its `plastic` or `roughplastic` over that texture). Emitter shapes keep their area emitter and get a black bsdf; point, spot and
//! directional lights and the sensors are written with the parameters kdmap read, transforms
//! as explicit row-major matrices, angles in degrees; an `envmap` with its `scale` and
//! `to_world`, its map copied to `textures/env_<k>.<ext>` (so the output directory stands on
//! its own), a `constant` with its radiance. Sample count is the `$spp` default.
//!
//! Shapes are written in input order, so shape indices (and `shape_<index>` ids) survive a
//! round trip through `scene::mitsuba::load`.

use super::page::html::esc;
use crate::base::error::Error;
use crate::base::fsio::write_atomic;
use crate::scene::{
    Emitter, EnvMap, FovAxis, KnownBsdf, PixelFilter, Rgb, Scene, Sensor, Shape, Sides,
};
use crate::Result;
use glam::{Mat4, Vec3};
use std::fmt::Write as _;
use std::path::Path;

/// Samples per pixel in the written scene (`<default name="spp">`).
pub const DEFAULT_SPP: u32 = 256;

fn rgb(c: Rgb) -> String {
    format!("{}, {}, {}", c.x, c.y, c.z)
}

fn xyz(v: Vec3) -> String {
    format!("x=\"{}\" y=\"{}\" z=\"{}\"", v.x, v.y, v.z)
}

/// A 4x4 matrix as Mitsuba's `<matrix value>`: 16 numbers, row-major.
fn matrix(m: &Mat4) -> String {
    (0..4)
        .flat_map(|r| m.row(r).to_array())
        .map(|v| v.to_string())
        .collect::<Vec<_>>()
        .join(" ")
}

fn fov_axis_name(a: FovAxis) -> &'static str {
    match a {
        FovAxis::X => "x",
        FovAxis::Y => "y",
        FovAxis::Diagonal => "diagonal",
        FovAxis::Smaller => "smaller",
        FovAxis::Larger => "larger",
    }
}

/// Radians (as kdmap keeps them) to the degrees Mitsuba reads, in double precision so the
/// value converts back to the same `f32`.
fn degrees(rad: f32) -> f64 {
    (rad as f64).to_degrees()
}

/// The `scene.xml` text for `scene`: meshes at `meshes/<id>.obj`, albedo textures at
/// `textures/<id>_albedo.exr`, both relative to the file; the shapes whose `folded[index]` is
/// set on their input UVs and folded albedo instead (`meshes/<id>_uv.obj`,
/// `textures/<id>_albedo_uv.exr`: see `uv_fold`); `sensors` in place of the scene's (the
/// same sensors at the poses the run used).
pub fn scene_xml(scene: &Scene, sensors: &[Sensor], folded: &[bool]) -> String {
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(w, "<?xml version=\"1.0\" encoding=\"utf-8\"?>");
    let _ = writeln!(
        w,
        "<!-- Written by kdmap from {}: the input's geometry, emitters and sensors with the\n     \
         recovered diffuse albedo (textures/*_albedo.exr, linear RGB). Render with\n     \
         mitsuba -D spp=64 scene.xml, or mi.load_file('scene.xml', spp=64). -->",
        esc(&scene.path.display().to_string().replace("--", "- -"))
    );
    let _ = writeln!(w, "<scene version=\"3.0.0\">");
    let _ = writeln!(w, "  <default name=\"spp\" value=\"{DEFAULT_SPP}\"/>");
    let _ = writeln!(
        w,
        "  <integrator type=\"path\"><integer name=\"max_depth\" value=\"-1\"/></integrator>"
    );

    for sensor in sensors {
        write_sensor(w, sensor);
    }
    for (k, e) in scene.emitters.iter().enumerate() {
        write_emitter(w, k, e);
    }
    for (i, shape) in scene.shapes.iter().enumerate() {
        write_shape(w, shape, folded.get(i).copied().unwrap_or(false));
    }
    let _ = writeln!(w, "</scene>");
    s
}

/// What Mitsuba's `perspective` sensor cannot hold of a COLMAP camera, as an XML comment
/// (empty for other sensors): its distortion, unequal focal lengths.
fn lens_comment(sensor: &Sensor) -> String {
    let Some(l) = &sensor.lens else {
        return String::new();
    };
    let mut lost = Vec::new();
    if l.distorts() {
        lost.push("its lens distortion");
    }
    if l.fx != l.fy {
        lost.push("fy != fx (Mitsuba's pixels are square)");
    }
    let lost = match lost.is_empty() {
        true => "nothing is lost".to_string(),
        false => format!("{} is not represented", lost.join(" and ")),
    };
    let text = format!(
        "COLMAP {} camera ({}) written as the nearest perspective sensor (fov from fx, \
         principal point offset from cx, cy): {lost}",
        l.model.name(),
        l.describe()
    );
    format!("  <!-- {} -->\n", esc(&text).replace("--", "- -"))
}

/// One `<sensor>` as Mitsuba reads it back (a COLMAP camera as the nearest one, with a
/// comment saying what is lost).
fn write_sensor(w: &mut String, sensor: &Sensor) {
    w.push_str(&lens_comment(sensor));
    let _ = writeln!(
        w,
        "  <sensor type=\"perspective\" id=\"{}\">",
        esc(&sensor.id)
    );
    let _ = writeln!(w, "    <float name=\"fov\" value=\"{}\"/>", sensor.fov);
    let _ = writeln!(
        w,
        "    <string name=\"fov_axis\" value=\"{}\"/>",
        fov_axis_name(sensor.fov_axis)
    );
    let _ = writeln!(
        w,
        "    <transform name=\"to_world\"><matrix value=\"{}\"/></transform>",
        matrix(&sensor.to_world)
    );
    let _ = writeln!(
        w,
        "    <sampler type=\"independent\"><integer name=\"sample_count\" value=\"$spp\"/></sampler>"
    );
    for (axis, v) in [
        ("x", sensor.principal_point.x),
        ("y", sensor.principal_point.y),
    ] {
        if v != 0.0 {
            let _ = writeln!(
                w,
                "    <float name=\"principal_point_offset_{axis}\" value=\"{v}\"/>"
            );
        }
    }
    let _ = writeln!(
        w,
        "    <film type=\"hdrfilm\"><integer name=\"width\" value=\"{}\"/><integer name=\"height\" value=\"{}\"/>\
         {}<string name=\"pixel_format\" value=\"rgb\"/>{}</film>",
        sensor.film_width,
        sensor.film_height,
        crop_window(sensor),
        rfilter(sensor.filter)
    );
    let _ = writeln!(w, "  </sensor>");
}

/// The film's crop window properties, empty for the whole film.
fn crop_window(s: &Sensor) -> String {
    if (s.width, s.height, s.crop_offset) == (s.film_width, s.film_height, (0, 0)) {
        return String::new();
    }
    format!(
        "<integer name=\"crop_offset_x\" value=\"{}\"/><integer name=\"crop_offset_y\" value=\"{}\"/>\
         <integer name=\"crop_width\" value=\"{}\"/><integer name=\"crop_height\" value=\"{}\"/>",
        s.crop_offset.0, s.crop_offset.1, s.width, s.height
    )
}

/// The film's `<rfilter>` with its parameter.
fn rfilter(f: PixelFilter) -> String {
    match f {
        PixelFilter::Box => "<rfilter type=\"box\"/>".to_string(),
        PixelFilter::Tent { radius } => {
            format!("<rfilter type=\"tent\"><float name=\"radius\" value=\"{radius}\"/></rfilter>")
        }
        PixelFilter::Gaussian { stddev } => format!(
            "<rfilter type=\"gaussian\"><float name=\"stddev\" value=\"{stddev}\"/></rfilter>"
        ),
    }
}

/// Where `scene.xml` finds the map of environment emitter `k`, relative to it (`None` for a
/// `constant`).
pub fn env_map_name(k: usize, env: &EnvMap) -> Option<String> {
    let ext = env.file.as_ref()?.extension().and_then(|e| e.to_str());
    Some(format!(
        "textures/env_{k}.{}",
        ext.unwrap_or("exr").to_ascii_lowercase()
    ))
}

/// One environment emitter (`k`: its index among the scene's emitters).
fn write_environment(w: &mut String, k: usize, env: &EnvMap) {
    let Some(name) = env_map_name(k, env) else {
        let _ = writeln!(
            w,
            "  <emitter type=\"constant\"><rgb name=\"radiance\" value=\"{}\"/></emitter>",
            rgb(env.radiance)
        );
        return;
    };
    let _ = writeln!(w, "  <emitter type=\"envmap\">");
    let _ = writeln!(
        w,
        "    <string name=\"filename\" value=\"{}\"/><float name=\"scale\" value=\"{}\"/>",
        esc(&name),
        env.scale
    );
    let _ = writeln!(
        w,
        "    <transform name=\"to_world\"><matrix value=\"{}\"/></transform>",
        matrix(&env.to_world)
    );
    let _ = writeln!(w, "  </emitter>");
}

/// One emitter (area emitters are written with their shape).
fn write_emitter(w: &mut String, k: usize, e: &Emitter) {
    match e {
        Emitter::Point {
            position,
            intensity,
        } => {
            let _ = writeln!(
                w,
                "  <emitter type=\"point\"><point name=\"position\" {}/><rgb name=\"intensity\" value=\"{}\"/></emitter>",
                xyz(*position),
                rgb(*intensity)
            );
        }
        Emitter::Spot {
            to_world,
            intensity,
            cutoff,
            beam_width,
            ..
        } => {
            let _ = writeln!(w, "  <emitter type=\"spot\">");
            let _ = writeln!(
                w,
                "    <transform name=\"to_world\"><matrix value=\"{}\"/></transform>",
                matrix(to_world)
            );
            let _ = writeln!(
                w,
                "    <rgb name=\"intensity\" value=\"{}\"/>",
                rgb(*intensity)
            );
            let _ = writeln!(
                w,
                "    <float name=\"cutoff_angle\" value=\"{}\"/><float name=\"beam_width\" value=\"{}\"/>",
                degrees(*cutoff),
                degrees(*beam_width)
            );
            let _ = writeln!(w, "  </emitter>");
        }
        Emitter::Directional {
            direction,
            irradiance,
        } => {
            let _ = writeln!(
                w,
                "  <emitter type=\"directional\"><vector name=\"direction\" {}/><rgb name=\"irradiance\" value=\"{}\"/></emitter>",
                xyz(*direction),
                rgb(*irradiance)
            );
        }
        // Written with their shape below.
        Emitter::Area { .. } => {}
        Emitter::Environment(env) => write_environment(w, k, env),
    }
}

/// One `<shape>`: its mesh, its recovered (or known) bsdf, its area emitter.
fn write_shape(w: &mut String, shape: &Shape, folded: bool) {
    let id = esc(&shape.id);
    let suffix = if folded { "_uv" } else { "" };
    let _ = writeln!(w, "  <shape type=\"obj\" id=\"{id}\">");
    let _ = writeln!(
        w,
        "    <string name=\"filename\" value=\"meshes/{id}{suffix}.obj\"/>"
    );
    if shape.mesh.normals.is_none() {
        // No `vn` in the file: keep the facets flat as kdmap saw them, rather than the
        // smooth normals Mitsuba would compute.
        let _ = writeln!(w, "    <boolean name=\"face_normals\" value=\"true\"/>");
    }
    if let Some(k) = shape.known() {
        let b = super::bsdf_xml::bsdf_xml(&k.bsdf);
        match (shape.sides, &k.bsdf) {
            (Sides::Both, KnownBsdf::Dielectric { .. } | KnownBsdf::Null) | (Sides::Front, _) => {
                let _ = writeln!(w, "    {b}");
            }
            (Sides::Both, _) => {
                let _ = writeln!(w, "    <bsdf type=\"twosided\">{b}</bsdf>");
            }
        }
        let _ = writeln!(w, "  </shape>");
        return;
    }
    let texture = format!("textures/{id}_albedo{suffix}.exr");
    let diffuse = if let Some(k) = shape.coated() {
        super::bsdf_xml::coated_xml(&k.bsdf, &texture)
    } else if shape.is_reconstructed() {
        format!(
            "<bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\
             <string name=\"filename\" value=\"{texture}\"/>\
             <boolean name=\"raw\" value=\"true\"/></texture></bsdf>"
        )
    } else {
        "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0\"/></bsdf>".to_string()
    };
    match shape.sides {
        Sides::Front => {
            let _ = writeln!(w, "    {diffuse}");
        }
        Sides::Both => {
            let _ = writeln!(w, "    <bsdf type=\"twosided\">{diffuse}</bsdf>");
        }
    }
    if let Some(r) = shape.emission {
        let _ = writeln!(
            w,
            "    <emitter type=\"area\"><rgb name=\"radiance\" value=\"{}\"/></emitter>",
            rgb(r)
        );
    }
    let _ = writeln!(w, "  </shape>");
}

/// Write `<out>/scene.xml` for `scene`, `sensors` and `folded` as in [`scene_xml`] (the
/// meshes and textures it names are written by the other parts of `output`).
pub fn write_scene_xml(
    out: &Path,
    scene: &Scene,
    sensors: &[Sensor],
    folded: &[bool],
) -> Result<()> {
    for (k, e) in scene.emitters.iter().enumerate() {
        if let Emitter::Environment(env) = e {
            if let (Some(src), Some(name)) = (&env.file, env_map_name(k, env)) {
                let bytes = std::fs::read(src).map_err(|e| Error::io(src, e))?;
                let dst = out.join(name);
                if let Some(d) = dst.parent() {
                    std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
                }
                write_atomic(&dst, &bytes)?;
            }
        }
    }
    let text = scene_xml(scene, sensors, folded);
    write_atomic(&out.join("scene.xml"), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::obj::write_shape_mesh;
    use crate::scene::mitsuba;

    /// Every emitter kind, a twosided shape, flat and smooth meshes, an unnamed shape:
    /// written (meshes + scene.xml) and loaded back by kdmap's own loader.
    #[test]
    fn every_emitter_kind_round_trips_through_the_loader() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.xml");
        std::fs::write(
            &input,
            "<scene version=\"3.0.0\">\
             <emitter type=\"point\"><point name=\"position\" value=\"1, 2.5, -3\"/>\
               <rgb name=\"intensity\" value=\"5, 4, 3.25\"/></emitter>\
             <emitter type=\"spot\"><transform name=\"to_world\">\
               <lookat origin=\"0.3, 5, 0.1\" target=\"0, 0, 0\" up=\"0, 0, 1\"/></transform>\
               <rgb name=\"intensity\" value=\"7\"/>\
               <float name=\"cutoff_angle\" value=\"37.5\"/><float name=\"beam_width\" value=\"21.25\"/></emitter>\
             <emitter type=\"directional\"><vector name=\"direction\" x=\"0.2\" y=\"-2\" z=\"0.1\"/>\
               <rgb name=\"irradiance\" value=\"1, 2, 3\"/></emitter>\
             <sensor type=\"perspective\" id=\"cam\"><float name=\"fov\" value=\"33.3\"/>\
               <string name=\"fov_axis\" value=\"smaller\"/>\
               <transform name=\"to_world\"><lookat origin=\"1, 2, 9\" target=\"0, 1, 0\" up=\"0, 1, 0\"/></transform>\
               <film type=\"hdrfilm\"><integer name=\"width\" value=\"64\"/><integer name=\"height\" value=\"48\"/></film></sensor>\
             <shape type=\"rectangle\" id=\"floor\"><transform name=\"to_world\"><rotate x=\"1\" angle=\"-90\"/>\
               <scale value=\"2\"/></transform><bsdf type=\"twosided\"><bsdf type=\"diffuse\"/></bsdf></shape>\
             <shape type=\"cube\"><boolean name=\"face_normals\" value=\"true\"/></shape>\
             <shape type=\"sphere\" id=\"lamp\"><point name=\"center\" x=\"0\" y=\"3\" z=\"0\"/><float name=\"radius\" value=\"0.25\"/>\
               <emitter type=\"area\"><rgb name=\"radiance\" value=\"3, 2, 1\"/></emitter></shape>\
             </scene>",
        )
        .unwrap();
        let a = mitsuba::load(&input).unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(&out).unwrap();
        for s in &a.shapes {
            write_shape_mesh(&out.join("meshes"), s, None).unwrap();
        }
        write_scene_xml(&out, &a, &a.sensors, &[]).unwrap();
        let b = mitsuba::load(&out.join("scene.xml")).unwrap();
        assert_same_scene(&a, &b);
    }

    /// Every known-material form kdmap reads is written back to a bsdf the loader reads to
    /// the same material (sides included); presets and named IORs come back as numbers.
    #[test]
    fn known_materials_round_trip_through_the_loader() {
        let shapes = [
            r#"<bsdf type="conductor"><string name="material" value="Au"/></bsdf>"#,
            r#"<bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/><rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/></bsdf>"#,
            r#"<bsdf type="dielectric"><string name="int_ior" value="diamond"/></bsdf>"#,
            r#"<bsdf type="roughdielectric"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>"#,
            r#"<bsdf type="thindielectric"/>"#,
            r#"<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.1, 0.2, 0.3"/><boolean name="nonlinear" value="true"/></bsdf>"#,
            r#"<bsdf type="roughplastic"><texture type="bitmap" name="diffuse_reflectance"><string name="filename" value="x.png"/></texture></bsdf>"#,
            r#"<bsdf type="principled"><rgb name="base_color" value="0.5, 0.1, 0.1"/><float name="metallic" value="0.3"/><float name="spec_trans" value="0.2"/></bsdf>"#,
            r#"<bsdf type="blendbsdf"><float name="weight" value="0.25"/><bsdf type="diffuse"><rgb name="reflectance" value="0.3"/></bsdf><bsdf type="conductor"/></bsdf>"#,
            r#"<bsdf type="mask"><float name="opacity" value="0.4"/><bsdf type="twosided"><bsdf type="conductor"/></bsdf></bsdf>"#,
            r#"<bsdf type="twosided"><bsdf type="plastic"/></bsdf>"#,
            r#"<bsdf type="twosided"><bsdf type="dielectric"/></bsdf>"#,
            r#"<bsdf type="null"/>"#,
            r#"<bsdf type="bumpmap"><texture type="bitmap"><string name="filename" value="b.png"/></texture><bsdf type="conductor"/></bsdf>"#,
        ];
        let body: String = shapes
            .iter()
            .map(|b| format!("<shape type=\"cube\">{b}</shape>"))
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.xml");
        std::fs::write(
            &input,
            format!("<scene version=\"3.0.0\"><emitter type=\"point\"/>{body}</scene>"),
        )
        .unwrap();
        let a = mitsuba::load(&input).unwrap();
        assert!(a.shapes.iter().all(|s| !s.is_reconstructed()));
        let out = dir.path().join("out");
        for s in &a.shapes {
            write_shape_mesh(&out.join("meshes"), s, None).unwrap();
        }
        write_scene_xml(&out, &a, &a.sensors, &[]).unwrap();
        let b = mitsuba::load(&out.join("scene.xml")).unwrap();
        for (s, t) in a.shapes.iter().zip(&b.shapes) {
            let (x, y) = (s.known().unwrap(), t.known().unwrap());
            assert_eq!(x.bsdf, y.bsdf, "{}", x.plugin);
            assert_eq!(s.sides, t.sides, "{}", x.plugin);
        }
        let au = crate::scene::material::metal_preset("Au").unwrap();
        match &a.shapes[0].known().unwrap().bsdf {
            KnownBsdf::Conductor { eta, k, .. } => assert_eq!((*eta, *k), au),
            other => panic!("{other:?}"),
        }
        match &a.shapes[2].known().unwrap().bsdf {
            KnownBsdf::Dielectric { eta, .. } => assert!((eta - 2.419 / 1.000277).abs() < 1e-6),
            other => panic!("{other:?}"),
        }
    }

    pub(crate) fn assert_same_scene(a: &Scene, b: &Scene) {
        let close3 =
            |x: Vec3, y: Vec3| (x - y).abs().max_element() <= 1e-5 * (1.0 + x.abs().max_element());
        assert_eq!(a.shapes.len(), b.shapes.len());
        for (s, t) in a.shapes.iter().zip(&b.shapes) {
            assert_eq!(s.id, t.id);
            assert_eq!(s.sides, t.sides, "{}", s.id);
            assert_eq!(s.emission, t.emission, "{}", s.id);
            assert_eq!(s.mesh.triangles.len(), t.mesh.triangles.len(), "{}", s.id);
            assert_eq!(
                s.mesh.normals.is_some(),
                t.mesh.normals.is_some(),
                "{}",
                s.id
            );
            for tri in 0..s.mesh.triangles.len() {
                let (p, q) = (s.mesh.triangle(tri), t.mesh.triangle(tri));
                for c in 0..3 {
                    assert!(
                        close3(p[c], q[c]),
                        "{} triangle {tri}: {p:?} vs {q:?}",
                        s.id
                    );
                }
                assert!(close3(
                    s.mesh.shading_normal(tri, 0.2, 0.3),
                    t.mesh.shading_normal(tri, 0.2, 0.3)
                ));
            }
        }
        assert_eq!(a.sensors.len(), b.sensors.len());
        for (s, t) in a.sensors.iter().zip(&b.sensors) {
            assert_eq!(
                (&s.id, s.fov_axis, s.width, s.height),
                (&t.id, t.fov_axis, t.width, t.height)
            );
            assert!((s.fov - t.fov).abs() <= 1e-5 * s.fov);
            assert!(s.to_world.abs_diff_eq(t.to_world, 1e-5), "{}", s.id);
        }
        assert_eq!(a.emitters.len(), b.emitters.len());
        for (e, f) in a.emitters.iter().zip(&b.emitters) {
            assert_same_emitter(e, f);
        }
    }

    /// `f` is `e` read back, within float rounding.
    fn assert_same_emitter(e: &Emitter, f: &Emitter) {
        let close3 =
            |x: Vec3, y: Vec3| (x - y).abs().max_element() <= 1e-5 * (1.0 + x.abs().max_element());
        match (e, f) {
            (
                Emitter::Point {
                    position: p,
                    intensity: i,
                },
                Emitter::Point {
                    position: q,
                    intensity: j,
                },
            ) => assert!(close3(*p, *q) && close3(*i, *j)),
            (
                Emitter::Spot {
                    position: p,
                    axis: a1,
                    to_world: m1,
                    intensity: i,
                    cutoff: c1,
                    beam_width: b1,
                },
                Emitter::Spot {
                    position: q,
                    axis: a2,
                    to_world: m2,
                    intensity: j,
                    cutoff: c2,
                    beam_width: b2,
                },
            ) => {
                assert!(close3(*p, *q) && close3(*a1, *a2) && close3(*i, *j));
                assert!(m1.abs_diff_eq(*m2, 1e-5));
                assert!(
                    (c1 - c2).abs() <= 1e-6 && (b1 - b2).abs() <= 1e-6,
                    "{c1} {c2} {b1} {b2}"
                );
            }
            (
                Emitter::Directional {
                    direction: d,
                    irradiance: i,
                },
                Emitter::Directional {
                    direction: g,
                    irradiance: j,
                },
            ) => assert!(close3(*d, *g) && close3(*i, *j)),
            (
                Emitter::Area {
                    shape: s,
                    radiance: r,
                },
                Emitter::Area {
                    shape: t,
                    radiance: q,
                },
            ) => assert!(s == t && close3(*r, *q)),
            _ => panic!("emitters differ: {e:?} vs {f:?}"),
        }
    }

    /// An envmap (its map copied next to scene.xml, scale and rotation kept) and a constant
    /// round-trip through the loader to the same radiance in every direction.
    #[test]
    fn environment_emitters_round_trip_with_their_map() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("in/sky")).unwrap();
        let px = |x: usize, y: usize| (x as f32 + 0.5, 1.0 + y as f32, 0.25 * (x * y) as f32);
        exr::prelude::write_rgb_file(dir.path().join("in/sky/map.exr"), 8, 5, px).unwrap();
        let input = dir.path().join("in/in.xml");
        std::fs::write(
            &input,
            "<scene version=\"3.0.0\">\
             <emitter type=\"envmap\"><string name=\"filename\" value=\"sky/map.exr\"/>\
               <float name=\"scale\" value=\"2.5\"/>\
               <transform name=\"to_world\"><rotate y=\"1\" angle=\"115.6\"/></transform></emitter>\
             <emitter type=\"constant\"><rgb name=\"radiance\" value=\"0.5, 1, 2\"/></emitter>\
             </scene>",
        )
        .unwrap();
        let a = mitsuba::load(&input).unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(&out).unwrap();
        write_scene_xml(&out, &a, &a.sensors, &[]).unwrap();
        assert!(out.join("textures/env_0.exr").is_file());
        let b = mitsuba::load(&out.join("scene.xml")).unwrap();
        assert_eq!(b.emitters.len(), 2);
        let envs = |s: &Scene| -> Vec<std::sync::Arc<EnvMap>> {
            s.emitters
                .iter()
                .map(|e| match e {
                    Emitter::Environment(env) => env.clone(),
                    _ => panic!("{e:?}"),
                })
                .collect()
        };
        let (ea, eb) = (envs(&a), envs(&b));
        assert!(ea[0].file.is_some() && eb[1].file.is_none());
        assert_eq!(eb[0].scale, 2.5);
        for d in [
            Vec3::X,
            Vec3::new(0.3, 0.5, -0.8),
            Vec3::new(-0.7, -0.1, 0.2),
        ] {
            for (x, y) in ea.iter().zip(&eb) {
                assert!((x.eval(d) - y.eval(d)).abs().max_element() < 1e-4);
            }
        }
        // the rotation moved the map: not the same as the unrotated one
        let raw = EnvMap::load(&dir.path().join("in/sky/map.exr"), 2.5, Mat4::IDENTITY).unwrap();
        assert!((raw.eval(Vec3::X) - eb[0].eval(Vec3::X)).length() > 0.1);
    }

    /// A folded shape is written on its input UVs (`meshes/<id>_uv.obj`) with the folded
    /// texture, the others on their atlas UVs; loaded back, its UVs are the input's (the OBJ's v
    /// convention round-trips through Mitsuba's default flip).
    #[test]
    fn a_folded_shape_is_written_on_its_input_uvs() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.xml");
        std::fs::write(
            &input,
            "<scene version=\"3.0.0\">\
             <shape type=\"rectangle\" id=\"floor\"><transform name=\"to_world\">\
               <scale value=\"2\"/></transform><bsdf type=\"diffuse\"/></shape>\
             <shape type=\"cube\" id=\"box\"/>\
             </scene>",
        )
        .unwrap();
        let mut a = mitsuba::load(&input).unwrap();
        for uv in a.shapes[0].mesh.uvs.as_mut().unwrap() {
            *uv = *uv * 20.0 + glam::Vec2::new(0.25, -3.0);
        }
        let out = dir.path().join("out");
        for s in &a.shapes {
            write_shape_mesh(&out.join("meshes"), s, None).unwrap();
        }
        crate::output::obj::write_shape_uv_mesh(&out.join("meshes"), &a.shapes[0]).unwrap();
        write_scene_xml(&out, &a, &a.sensors, &[true, false]).unwrap();
        let text = std::fs::read_to_string(out.join("scene.xml")).unwrap();
        assert!(
            text.contains("meshes/floor_uv.obj") && text.contains("textures/floor_albedo_uv.exr")
        );
        assert!(text.contains("meshes/box.obj") && text.contains("textures/box_albedo.exr"));
        assert!(!text.contains("floor_albedo.exr") && !text.contains("box_uv"));
        let b = mitsuba::load(&out.join("scene.xml")).unwrap();
        let (ua, ub) = (
            a.shapes[0].mesh.uvs.as_ref().unwrap(),
            b.shapes[0].mesh.uvs.as_ref().unwrap(),
        );
        assert_eq!(ua.len(), ub.len());
        for (x, y) in ua.iter().zip(ub) {
            assert!((*x - *y).length() < 1e-4, "{x} vs {y}");
        }
    }

    #[test]
    fn attribute_values_are_escaped() {
        assert_eq!(esc("a&b<\"c\">'"), "a&amp;b&lt;&quot;c&quot;&gt;&#39;");
        let m = Mat4::from_cols_array(&[
            1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0, 16.0,
        ]);
        // glam is column-major: the first row holds every column's x.
        assert!(matrix(&m).starts_with("1 5 9 13 2 6"));
    }
}
