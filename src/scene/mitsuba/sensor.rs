//! The camera side of a Mitsuba 3 scene: `<sensor type="perspective">` with its `<film
//! type="hdrfilm">`, `<rfilter>` and `<sampler>`, and the top-level `<integrator>`. Split
//! from `mitsuba.rs` so the property lists of these plugins sit in one place.
//!
//! Accepted as Mitsuba 3.9 accepts them (`src/sensors/perspective.cpp`,
//! `src/render/sensor.cpp`, `src/render/film.cpp`, `src/films/hdrfilm.cpp`,
//! `src/rfilters/*.cpp`, `src/samplers/*.cpp`, `src/render/sampler.cpp`):
//! - perspective: `to_world`, `fov`, `fov_axis`, `focal_length` (used), `principal_point_offset_x/y`
//!   (used), `near_clip`, `far_clip`, `focus_distance`, `shutter_open`, `shutter_close`
//!   (checked as Mitsuba checks them, then read past: a pinhole camera of a still scene);
//! - hdrfilm: `width`, `height`, `crop_offset_x/y`, `crop_width/height` (used: the photo is
//!   the crop window), `sample_border`, `file_format`, `pixel_format`, `component_format`,
//!   `banner`, `compensate` (read past), one `<rfilter>`: `box`, `tent` (`radius`),
//!   `gaussian` (`stddev`), the default;
//! - samplers `independent`, `stratified`, `multijitter`, `orthogonal`, `ldsampler` with
//!   `sample_count`, `seed`, `jitter`, `strength` (where the plugin has them);
//! - any integrator Mitsuba 3.9 ships, with whatever it holds (it cannot change the answer).

use super::{Parser, Props};
use crate::scene::filter::{DEFAULT_GAUSSIAN_STDDEV, DEFAULT_TENT_RADIUS};
use crate::scene::{FovAxis, PixelFilter, Sensor};
use crate::Result;
use glam::{DMat3, DMat4, Vec2};
use roxmltree::Node;

/// Mitsuba's film size when a sensor has no `<film>`.
pub const DEFAULT_FILM: (u32, u32) = (768, 576);

/// Mitsuba 3.9's integrator plugins (C++ and Python).
const INTEGRATORS: &[&str] = &[
    "path",
    "direct",
    "volpath",
    "volpathmis",
    "aov",
    "moment",
    "depth",
    "ptracer",
    "stokes",
    "prb",
    "prb_basic",
    "prb_projective",
    "prbvolpath",
    "direct_projective",
    "volprim_rf_basic",
];

/// Mitsuba 3.9's sensor plugins kdmap does not model yet.
const OTHER_SENSORS: &[&str] = &[
    "thinlens",
    "orthographic",
    "radiancemeter",
    "irradiancemeter",
    "distant",
    "batch",
];

/// Properties of the perspective sensor that cannot change what a photo shows of a still
/// scene through a pinhole (after the checks of [`Parser::clip_and_shutter`]).
const SENSOR_READ_PAST: &[&str] = &[
    "near_clip",
    "far_clip",
    "focus_distance",
    "shutter_open",
    "shutter_close",
];

/// What kdmap keeps of a film.
struct Film {
    size: (u32, u32),
    crop_offset: (u32, u32),
    crop_size: (u32, u32),
    filter: PixelFilter,
}

impl Default for Film {
    fn default() -> Film {
        Film {
            size: DEFAULT_FILM,
            crop_offset: (0, 0),
            crop_size: DEFAULT_FILM,
            filter: PixelFilter::default(),
        }
    }
}

impl<'a, 'i> Parser<'a, 'i> {
    pub(super) fn sensor(&mut self, node: Node<'a, 'i>, index: usize) -> Result<Sensor> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        if kind != "perspective" {
            let msg = if OTHER_SENSORS.contains(&kind.as_str()) {
                format!("sensor '{kind}' is not supported yet (only 'perspective')")
            } else {
                format!("unknown sensor plugin '{kind}'")
            };
            return Err(self.err(node, msg));
        }
        let id = self
            .attr(node, "id")?
            .unwrap_or_else(|| format!("sensor_{index}"));
        self.register_id(node, &id)?;
        let mut props = self.props(node)?;
        if let Some(n) = props.take("srf") {
            return Err(self.err(
                n,
                "a sensor response function ('srf') is not supported (photos are RGB)",
            ));
        }
        let fov = self.sensor_fov(&mut props)?;
        let to_world = self.camera_frame(&mut props)?;
        let principal_point = Vec2::new(
            self.opt_float(&mut props, "principal_point_offset_x")?
                .unwrap_or(0.0) as f32,
            self.opt_float(&mut props, "principal_point_offset_y")?
                .unwrap_or(0.0) as f32,
        );
        self.clip_and_shutter(&mut props)?;
        let objects = props.finish(self, SENSOR_READ_PAST)?;
        let film = self.sensor_objects(objects)?;
        let (fov, fov_axis) = fov;
        Ok(Sensor {
            id,
            to_world: to_world.as_mat4(),
            fov: fov as f32,
            fov_axis,
            width: film.crop_size.0,
            height: film.crop_size.1,
            film_width: film.size.0,
            film_height: film.size.1,
            crop_offset: film.crop_offset,
            principal_point,
            filter: film.filter,
            lens: None,
            photo: None,
        })
    }

    /// A sensor's film (Mitsuba's default `hdrfilm` if it has none) after checking its
    /// sampler; media are refused.
    fn sensor_objects(&self, objects: Vec<Node<'a, 'i>>) -> Result<Film> {
        let mut film = None;
        let mut have_sampler = false;
        for o in objects {
            match o.tag_name().name() {
                "film" => {
                    if film.is_some() {
                        return Err(self.err(o, "only one film can be specified per sensor"));
                    }
                    film = Some(self.film(o)?);
                }
                "sampler" => {
                    if have_sampler {
                        return Err(self.err(o, "only one sampler can be specified per sensor"));
                    }
                    have_sampler = true;
                    self.sampler(o)?;
                }
                "medium" => {
                    return Err(self.err(o, "participating media are not supported"));
                }
                other => {
                    return Err(self.err(o, format!("unsupported element <{other}> in a sensor")))
                }
            }
        }
        Ok(film.unwrap_or_default())
    }

    /// An optional float property.
    fn opt_float(&self, props: &mut Props<'a, 'i>, name: &str) -> Result<Option<f64>> {
        props.take(name).map(|n| self.float_of(n)).transpose()
    }

    /// `near_clip`, `far_clip`, `focus_distance`, `shutter_open`, `shutter_close`: checked as
    /// Mitsuba checks them (and left in `props`, to be read past).
    fn clip_and_shutter(&self, props: &mut Props<'a, 'i>) -> Result<()> {
        let val = |props: &mut Props<'a, 'i>, name: &str| -> Result<Option<(f64, Node<'a, 'i>)>> {
            let Some(n) = props.peek(name) else {
                return Ok(None);
            };
            Ok(Some((self.float_of(n)?, n)))
        };
        let near = val(props, "near_clip")?;
        let far = val(props, "far_clip")?;
        val(props, "focus_distance")?;
        let (near_v, far_v) = (near.map_or(1e-2, |v| v.0), far.map_or(1e4, |v| v.0));
        if let Some((v, n)) = near {
            if v <= 0.0 {
                return Err(self.err(n, "'near_clip' must be greater than zero"));
            }
        }
        if near_v >= far_v {
            let n = far.or(near).map(|v| v.1);
            return Err(self.err(
                n.unwrap_or(self.doc.root_element()),
                "'near_clip' must be smaller than 'far_clip'",
            ));
        }
        let open = val(props, "shutter_open")?;
        let close = val(props, "shutter_close")?;
        if close.map_or(0.0, |v| v.0) < open.map_or(0.0, |v| v.0) {
            let n = close.or(open).map(|v| v.1);
            return Err(self.err(
                n.unwrap_or(self.doc.root_element()),
                "'shutter_open' must not be later than 'shutter_close'",
            ));
        }
        Ok(())
    }

    /// A sensor's `fov` and `fov_axis`, or its `focal_length` as a diagonal fov (Mitsuba's
    /// defaults when absent).
    fn sensor_fov(&self, props: &mut Props<'a, 'i>) -> Result<(f64, FovAxis)> {
        let fov_node = props.take("fov");
        let axis_node = props.take("fov_axis");
        let focal = props.take("focal_length");
        if let (Some(_), Some(f)) = (fov_node, focal) {
            return Err(self.err(f, "give either 'fov' or 'focal_length', not both"));
        }
        let Some(n) = fov_node else {
            if let Some(a) = axis_node {
                return Err(self.err(a, "'fov_axis' without 'fov'"));
            }
            let mm = match focal {
                Some(f) => self.focal_length_of(f)?,
                None => 50.0,
            };
            // A focal length on a 36 x 24 mm film, as a diagonal fov.
            let diag = (36.0f64 * 36.0 + 24.0 * 24.0).sqrt();
            let fov = (2.0 * (diag / (2.0 * mm)).atan()).to_degrees();
            return Ok((fov, FovAxis::Diagonal));
        };
        let f = self.float_of(n)?;
        if !(f > 0.0 && f < 180.0) {
            return Err(self.err(n, "'fov' must be in (0, 180) degrees"));
        }
        let axis = match axis_node {
            Some(a) => {
                let s = self.string_of(a)?;
                match s.trim().to_ascii_lowercase().as_str() {
                    "x" => FovAxis::X,
                    "y" => FovAxis::Y,
                    "diagonal" => FovAxis::Diagonal,
                    "smaller" => FovAxis::Smaller,
                    "larger" => FovAxis::Larger,
                    _ => {
                        return Err(self.err(
                            a,
                            format!("invalid fov_axis '{s}' (x, y, diagonal, smaller, larger)"),
                        ))
                    }
                }
            }
            None => FovAxis::X,
        };
        Ok((f, axis))
    }

    /// Mitsuba's `focal_length`: a `<string>` `"<x>mm"` or `"<x>"`, millimetres on 35 mm film.
    fn focal_length_of(&self, n: Node) -> Result<f64> {
        let s = self.string_of(n)?;
        let t = s.trim();
        let t = t.strip_suffix("mm").unwrap_or(t);
        match t.trim().parse::<f64>() {
            Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
            _ => Err(self.err(
                n,
                format!(
                    "invalid focal_length '{s}' (a positive number of millimetres, e.g. '50mm')"
                ),
            )),
        }
    }

    /// A sensor's `to_world`: rotation and translation only, as Mitsuba requires.
    fn camera_frame(&self, props: &mut Props<'a, 'i>) -> Result<DMat4> {
        Ok(match self.to_world(props)? {
            Some((m, n)) => {
                let l = DMat3::from_mat4(m);
                let cols = [l.x_axis, l.y_axis, l.z_axis];
                let ortho = cols.iter().all(|c| (c.length() - 1.0).abs() <= 1e-3)
                    && l.x_axis.dot(l.y_axis).abs() <= 1e-3
                    && l.y_axis.dot(l.z_axis).abs() <= 1e-3
                    && l.x_axis.dot(l.z_axis).abs() <= 1e-3;
                if !ortho {
                    return Err(self.err(
                        n,
                        "scale or shear in a camera's to_world is not allowed (as in Mitsuba)",
                    ));
                }
                m
            }
            None => DMat4::IDENTITY,
        })
    }

    /// An `hdrfilm`: its size, crop window and filter; its output settings are checked and
    /// read past.
    fn film(&self, node: Node<'a, 'i>) -> Result<Film> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        match kind.as_str() {
            "hdrfilm" => {}
            "specfilm" => {
                return Err(self.err(node, "film 'specfilm' is not supported (only 'hdrfilm')"))
            }
            _ => return Err(self.err(node, format!("unknown film plugin '{kind}'"))),
        }
        let mut props = self.props(node)?;
        let size = (
            self.dim(&mut props, "width", DEFAULT_FILM.0, 1)?,
            self.dim(&mut props, "height", DEFAULT_FILM.1, 1)?,
        );
        let crop_size = (
            self.dim(&mut props, "crop_width", size.0, 1)?,
            self.dim(&mut props, "crop_height", size.1, 1)?,
        );
        let crop_offset = (
            self.dim(&mut props, "crop_offset_x", 0, 0)?,
            self.dim(&mut props, "crop_offset_y", 0, 0)?,
        );
        if crop_offset.0 as u64 + crop_size.0 as u64 > size.0 as u64
            || crop_offset.1 as u64 + crop_size.1 as u64 > size.1 as u64
        {
            return Err(self.err(node, "the crop window does not fit on the film"));
        }
        if let Some(n) = props.take("sample_border") {
            self.bool_of(n)?;
        }
        self.film_formats(&mut props)?;
        let mut filter = None;
        for o in &props.objects {
            if o.tag_name().name() != "rfilter" {
                return Err(self.err(
                    *o,
                    format!("unsupported element <{}> in a film", o.tag_name().name()),
                ));
            }
            if filter.replace(self.rfilter(*o)?).is_some() {
                return Err(self.err(*o, "a film can only have one reconstruction filter"));
            }
        }
        // `banner` and `compensate` are accepted and ignored by Mitsuba 3 itself.
        props.finish(self, &["banner", "compensate"])?;
        Ok(Film {
            size,
            crop_offset,
            crop_size,
            filter: filter.unwrap_or_default(),
        })
    }

    /// A film dimension (`<integer>`, at least `min`, at most 65536), `default` if absent.
    fn dim(&self, props: &mut Props<'a, 'i>, name: &str, default: u32, min: i64) -> Result<u32> {
        match props.take(name) {
            Some(n) => {
                let v = self.int_of(n)?;
                if !(min..=1 << 16).contains(&v) {
                    return Err(self.err(n, format!("'{name}' must be in {min}..=65536")));
                }
                Ok(v as u32)
            }
            None => Ok(default),
        }
    }

    /// `file_format`, `pixel_format`, `component_format`: one of the values Mitsuba knows.
    fn film_formats(&self, props: &mut Props<'a, 'i>) -> Result<()> {
        let choices: [(&str, &[&str]); 3] = [
            ("file_format", &["openexr", "exr", "rgbe", "pfm"]),
            (
                "pixel_format",
                &["luminance", "luminance_alpha", "rgb", "rgba", "xyz", "xyza"],
            ),
            ("component_format", &["float16", "float32", "uint32"]),
        ];
        for (name, allowed) in choices {
            if let Some(n) = props.take(name) {
                let v = self.string_of(n)?;
                if !allowed.contains(&v.trim().to_ascii_lowercase().as_str()) {
                    return Err(self.err(
                        n,
                        format!("invalid {name} '{v}' (one of {})", allowed.join(", ")),
                    ));
                }
            }
        }
        Ok(())
    }

    /// A film's `<rfilter>`.
    fn rfilter(&self, node: Node<'a, 'i>) -> Result<PixelFilter> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        let mut props = self.props(node)?;
        let mut positive = |name: &str, default: f32| -> Result<f32> {
            match props.take(name) {
                Some(n) => {
                    let v = self.float_of(n)?;
                    if !(v > 0.0 && v <= 64.0) {
                        return Err(self.err(n, format!("'{name}' must be in (0, 64] pixels")));
                    }
                    Ok(v as f32)
                }
                None => Ok(default),
            }
        };
        let f = match kind.as_str() {
            "box" => PixelFilter::Box,
            "tent" => PixelFilter::Tent {
                radius: positive("radius", DEFAULT_TENT_RADIUS)?,
            },
            "gaussian" => PixelFilter::Gaussian {
                stddev: positive("stddev", DEFAULT_GAUSSIAN_STDDEV)?,
            },
            "mitchell" | "catmullrom" | "lanczos" => {
                return Err(self.err(
                    node,
                    format!("rfilter '{kind}' is not supported yet (box, tent or gaussian)"),
                ))
            }
            _ => return Err(self.err(node, format!("unknown rfilter plugin '{kind}'"))),
        };
        if let Some(o) = props.objects.first() {
            return Err(self.err(*o, "an rfilter has no nested objects"));
        }
        props.finish(self, &[])?;
        Ok(f)
    }

    /// A `<sampler>`: a known plugin with the properties it takes (all read past).
    pub(super) fn sampler(&self, node: Node<'a, 'i>) -> Result<()> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        let extra: &[&str] = match kind.as_str() {
            "independent" | "ldsampler" => &[],
            "stratified" | "multijitter" => &["jitter"],
            "orthogonal" => &["jitter", "strength"],
            _ => return Err(self.err(node, format!("unknown sampler plugin '{kind}'"))),
        };
        let props = self.props(node)?;
        for name in ["sample_count", "seed", "strength"] {
            if let Some(n) = props.peek(name) {
                self.int_of(n)?;
            }
        }
        if let Some(n) = props.peek("jitter") {
            self.bool_of(n)?;
        }
        if let Some(o) = props.objects.first() {
            return Err(self.err(*o, "a sampler has no nested objects"));
        }
        let mut read_past = vec!["sample_count", "seed"];
        read_past.extend_from_slice(extra);
        props.finish(self, &read_past)?;
        Ok(())
    }

    /// An `<integrator>`: any plugin Mitsuba 3.9 ships, read past with what it holds.
    pub(super) fn integrator(&self, node: Node<'a, 'i>) -> Result<()> {
        let kind = self.req_attr(node, "type")?;
        if !INTEGRATORS.contains(&kind.as_str()) {
            return Err(self.err(node, format!("unknown integrator plugin '{kind}'")));
        }
        self.check_attrs(node, &["type", "id", "name"])
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse;
    use crate::scene::{FovAxis, PixelFilter, Scene};
    use glam::Vec2;
    use std::path::Path;

    fn scene(body: &str) -> crate::Result<Scene> {
        parse(
            &format!("<scene version=\"3.0.0\">\n{body}\n</scene>"),
            Path::new("s/scene.xml"),
        )
    }

    /// Every property Mitsuba 3.9's perspective sensor, hdrfilm, tent filter and stratified
    /// sampler accept parses; the ones that shape the photo are kept.
    #[test]
    fn every_accepted_sensor_property_parses() {
        let s = scene(
            r#"<integrator type="prb" name="integrator"><integer name="max_depth" value="-1"/>
                 <integer name="rr_depth" value="8"/><boolean name="hide_emitters" value="true"/></integrator>
               <sensor type="perspective" id="cam" name="sensor">
                 <float name="fov" value="39.3077"/><string name="fov_axis" value="smaller"/>
                 <float name="near_clip" value="0.001"/><float name="far_clip" value="100.0"/>
                 <float name="focus_distance" value="1000"/>
                 <float name="principal_point_offset_x" value="0.1"/>
                 <float name="principal_point_offset_y" value="-0.25"/>
                 <float name="shutter_open" value="0"/><float name="shutter_close" value="1"/>
                 <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
                 <sampler type="stratified" name="sampler"><integer name="sample_count" value="64"/>
                   <integer name="seed" value="3"/><boolean name="jitter" value="false"/></sampler>
                 <film type="hdrfilm" name="film">
                   <integer name="width" value="64"/><integer name="height" value="48"/>
                   <integer name="crop_offset_x" value="4"/><integer name="crop_offset_y" value="2"/>
                   <integer name="crop_width" value="32"/><integer name="crop_height" value="40"/>
                   <boolean name="sample_border" value="true"/>
                   <string name="file_format" value="openexr"/><string name="pixel_format" value="rgb"/>
                   <string name="component_format" value="float32"/>
                   <boolean name="banner" value="false"/><boolean name="compensate" value="true"/>
                   <rfilter type="tent" name="filter"><float name="radius" value="1.5"/></rfilter>
                 </film>
               </sensor>"#,
        )
        .unwrap();
        let c = &s.sensors[0];
        assert_eq!(c.id, "cam");
        assert_eq!((c.fov, c.fov_axis), (39.3077, FovAxis::Smaller));
        assert_eq!(c.principal_point, Vec2::new(0.1, -0.25));
        assert_eq!((c.film_width, c.film_height), (64, 48));
        assert_eq!((c.width, c.height, c.crop_offset), (32, 40, (4, 2)));
        assert_eq!(c.filter, PixelFilter::Tent { radius: 1.5 });
    }

    #[test]
    fn filters_parse_with_mitsubas_defaults() {
        let film = |f: &str| {
            let s = scene(&format!(
                "<sensor type=\"perspective\"><film type=\"hdrfilm\">{f}</film></sensor>"
            ))
            .unwrap();
            s.sensors[0].filter
        };
        assert_eq!(
            film("<rfilter type=\"tent\"/>"),
            PixelFilter::Tent { radius: 1.0 }
        );
        assert_eq!(film("<rfilter type=\"box\"/>"), PixelFilter::Box);
        assert_eq!(
            film("<rfilter type=\"gaussian\"><float name=\"stddev\" value=\"0.3\"/></rfilter>"),
            PixelFilter::Gaussian { stddev: 0.3 }
        );
        // No rfilter, or no film at all: Mitsuba's gaussian of stddev 0.5.
        assert_eq!(film(""), PixelFilter::Gaussian { stddev: 0.5 });
        let s = scene("<sensor type=\"perspective\"/>").unwrap();
        assert_eq!(s.sensors[0].filter, PixelFilter::Gaussian { stddev: 0.5 });
    }

    /// Sensors without an id are `sensor_<index>` among the sensors (their photo is
    /// `images/sensor_<index>.exr`); a `name` attribute changes nothing.
    #[test]
    fn sensors_without_id_and_name_attributes() {
        let s = scene(
            "<sensor type=\"perspective\" name=\"a\"/><sensor type=\"perspective\" id=\"main\"/>\
             <sensor type=\"perspective\"/>\
             <shape type=\"rectangle\" name=\"floor\"><emitter type=\"area\" name=\"emitter\">\
               <rgb value=\"2\" name=\"radiance\"/></emitter></shape>\
             <emitter type=\"point\" name=\"p\"/>",
        )
        .unwrap();
        let ids: Vec<_> = s.sensors.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["sensor_0", "main", "sensor_2"]);
        assert_eq!(s.shapes[0].id, "shape_0");
        assert_eq!(s.emitters.len(), 2);
    }

    #[test]
    fn focal_length_is_a_diagonal_fov() {
        let s = scene(
            "<sensor type=\"perspective\"><string name=\"focal_length\" value=\"35mm\"/></sensor>",
        )
        .unwrap();
        let want = (2.0 * (43.2666f64 / 70.0).atan()).to_degrees() as f32;
        assert!(
            (s.sensors[0].fov - want).abs() < 1e-3,
            "{}",
            s.sensors[0].fov
        );
        assert_eq!(s.sensors[0].fov_axis, FovAxis::Diagonal);
    }

    /// Properties Mitsuba itself would reject are refused with file, line and element.
    #[test]
    fn properties_mitsuba_rejects_are_refused_with_line_and_element() {
        let cases = [
            (
                "<sensor type=\"perspective\">\n<float name=\"x_fov\" value=\"30\"/></sensor>",
                "s/scene.xml (line 3, col 1), <float name=\"x_fov\">: unsupported property 'x_fov' on <sensor type=\"perspective\">",
            ),
            (
                "<sensor type=\"perspective\"><film type=\"hdrfilm\">\n<integer name=\"depth\" value=\"3\"/></film></sensor>",
                "s/scene.xml (line 3, col 1), <integer name=\"depth\">: unsupported property 'depth' on <film type=\"hdrfilm\">",
            ),
            (
                "<sensor type=\"perspective\"><film type=\"hdrfilm\">\n<rfilter type=\"box\"><float name=\"radius\" value=\"1\"/></rfilter></film></sensor>",
                "s/scene.xml (line 3, col 21), <float name=\"radius\">: unsupported property 'radius' on <rfilter type=\"box\">",
            ),
            (
                "<sensor type=\"perspective\"><float name=\"fov\" value=\"30\"/>\n<string name=\"focal_length\" value=\"50mm\"/></sensor>",
                "(line 3, col 1), <string name=\"focal_length\">: give either 'fov' or 'focal_length'",
            ),
        ];
        for (body, want) in cases {
            let e = scene(body).unwrap_err().to_string();
            assert!(e.contains(want), "{body}: {e}");
            assert!(!e.contains('\n'));
        }
    }
}
