use super::*;
use crate::base::error::exit;
use ::image::{ImageBuffer, Luma, LumaA, Rgb, RgbImage, Rgba};

fn close(a: f32, b: f64, rel: f64) -> bool {
    (a as f64 - b).abs() <= rel * b.abs().max(1e-12)
}

#[test]
fn srgb_decode_of_known_codes_is_the_closed_form() {
    // IEC 61966-2-1: v / 12.92 up to 0.04045, else ((v + 0.055) / 1.055)^2.4, v = code / 255
    let lut = response_lut(&Response::Srgb, 255);
    assert_eq!(lut.len(), 256);
    assert_eq!(lut[0], 0.0);
    for (code, want) in [
        (1, 1.0 / 255.0 / 12.92),
        (10, 10.0 / 255.0 / 12.92),
        (11, ((11.0 / 255.0 + 0.055) / 1.055f64).powf(2.4)),
        (128, 0.215_860_500_113_899_26),
        (254, 0.991_102_097_113_829_8),
    ] {
        assert!(close(lut[code], want, 1e-6), "code {code}: {}", lut[code]);
    }
    assert_eq!(lut[255], 1.0);
    assert!(lut.windows(2).all(|w| w[1] > w[0]));
    // 16 bits: the same curve on code / 65535
    let deep = response_lut(&Response::Srgb, 65535);
    assert!(close(deep[32768], 0.214_048_202_298_185_2, 1e-6));
    assert!(close(deep[514], 0.000_607_053_967_097_675, 1e-6));
    assert_eq!(deep[65535], 1.0);
}

#[test]
fn gamma_linear_and_table_responses() {
    let gamma = response_lut(&Response::Gamma(2.2), 255);
    assert!(close(gamma[128], 0.219_519_718_074_867_9, 1e-6));
    assert_eq!((gamma[0], gamma[255]), (0.0, 1.0));
    let linear = response_lut(&Response::Linear, 255);
    assert!(close(linear[51], 0.2, 1e-6));
    // a measured curve: code c is worth (c / 255)^3 * 0.8
    let t: Vec<f32> = (0..256).map(|c| (c as f32 / 255.0).powi(3) * 0.8).collect();
    let table = response_lut(&Response::Table(t.clone()), 255);
    assert_eq!(table, t, "8-bit codes read the table exactly");
    let deep = response_lut(&Response::Table(t.clone()), 65535);
    assert_eq!(deep[128 * 257], t[128]);
    assert_eq!(deep[65535], t[255]);
    // halfway between codes 128 and 129 of 255
    let half = 128 * 257 + 128;
    let x = half as f64 * 255.0 / 65535.0 - 128.0;
    let want = t[128] as f64 * (1.0 - x) + t[129] as f64 * x;
    assert!(close(deep[half], want, 1e-6), "{} vs {want}", deep[half]);
}

/// `unknown` over a `w` x `h` image whose pixels are all `fill` but those of `set`.
fn mask_of(w: u32, h: u32, fill: [u32; 3], set: &[(u32, u32, [u32; 3])], ring: u32) -> Vec<bool> {
    let codes = |i: usize| {
        let (x, y) = (i as u32 % w, i as u32 / w);
        set.iter()
            .find(|s| (s.0, s.1) == (x, y))
            .map_or(fill, |s| s.2)
    };
    unknown(w, h, codes, 255, DARK_CODE, ring)
}

fn masked_at(m: &[bool], w: u32) -> Vec<(u32, u32)> {
    (m.iter().enumerate())
        .filter(|(_, &b)| b)
        .map(|(i, _)| (i as u32 % w, i as u32 / w))
        .collect()
}

#[test]
fn clipped_pixels_are_masked_and_in_a_jpeg_their_ring_too() {
    let grey = [120, 110, 100];
    let one_red_clip = [(2, 2, [255, 40, 30])];
    assert_eq!(
        masked_at(&mask_of(5, 5, grey, &one_red_clip, 0), 5),
        [(2, 2)]
    );
    let ring = masked_at(&mask_of(5, 5, grey, &one_red_clip, JPEG_RING), 5);
    let want: Vec<(u32, u32)> = (1..4).flat_map(|y| (1..4).map(move |x| (x, y))).collect();
    assert_eq!(ring, want, "the 3 x 3 block around the clipped pixel");
    // at a corner the ring stops at the border; 254 is not clipped
    let corner = [(0, 0, [10, 255, 10]), (4, 4, [254, 254, 254])];
    assert_eq!(
        masked_at(&mask_of(5, 5, grey, &corner, JPEG_RING), 5),
        [(0, 0), (1, 0), (0, 1), (1, 1)]
    );
    assert!(masked_at(&mask_of(5, 5, grey, &[], JPEG_RING), 5).is_empty());
}

#[test]
fn near_black_pixels_are_masked_only_when_every_channel_is_dark() {
    let grey = [120, 110, 100];
    let set = [
        (0, 0, [2, 2, 2]),
        (1, 0, [0, 0, 0]),
        (2, 0, [1, 2, 0]),
        (3, 0, [2, 2, 3]),
        (4, 0, [3, 3, 3]),
        (0, 1, [0, 0, 200]),
    ];
    let m = mask_of(5, 2, grey, &set, JPEG_RING);
    assert_eq!(masked_at(&m, 5), [(0, 0), (1, 0), (2, 0)]);
}

fn write_png<P: ::image::Pixel<Subpixel = S> + ::image::PixelWithColorType, S>(
    path: &Path,
    img: &ImageBuffer<P, Vec<S>>,
) where
    [S]: ::image::EncodableLayout,
{
    img.save(path).unwrap();
}

#[test]
fn a_png_is_read_through_the_response_with_its_masks() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cam.png");
    let codes = [
        [128, 64, 32],
        [255, 10, 10],
        [2, 1, 0],
        [3, 3, 3],
        [254, 200, 1],
        [7, 8, 9],
    ];
    let img = RgbImage::from_fn(3, 2, |x, y| {
        Rgb(codes[(y * 3 + x) as usize].map(|c| c as u8))
    });
    write_png(&p, &img);
    let srgb = response_lut(&Response::Srgb, 255);
    let got = read_ldr(&p, &Response::Srgb).unwrap();
    assert_eq!((got.width, got.height, got.masked), (3, 2, 2));
    assert_eq!(got.valid, [true, false, false, true, true, true]);
    for (i, c) in codes.iter().enumerate() {
        let want = match got.valid[i] {
            true => Vec3::from_array(c.map(|c| srgb[c as usize])),
            false => Vec3::ZERO,
        };
        assert_eq!(got.pixels[i], want, "pixel {i}");
    }
    // another response, the same file
    let lin = read_ldr(&p, &Response::Linear).unwrap();
    assert!(close(lin.pixels[0].x, 128.0 / 255.0, 1e-6));
}

#[test]
fn grey_alpha_and_16_bit_pngs_are_read_as_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let grey = dir.path().join("grey.png");
    write_png(
        &grey,
        &ImageBuffer::from_fn(2, 1, |x, _| Luma([100u8 + x as u8])),
    );
    let g = read_ldr(&grey, &Response::Linear).unwrap();
    assert_eq!(g.pixels[1], Vec3::splat(101.0 / 255.0));
    let alpha = dir.path().join("alpha.png");
    write_png(
        &alpha,
        &ImageBuffer::from_fn(1, 1, |_, _| Rgba([10u8, 20, 30, 0])),
    );
    let a = read_ldr(&alpha, &Response::Linear).unwrap();
    assert_eq!(
        a.pixels[0],
        Vec3::new(10.0, 20.0, 30.0) / 255.0,
        "alpha ignored"
    );
    let la = dir.path().join("la.png");
    write_png(&la, &ImageBuffer::from_fn(1, 1, |_, _| LumaA([50u8, 255])));
    assert_eq!(read_ldr(&la, &Response::Linear).unwrap().masked, 0);

    let deep = dir.path().join("deep.png");
    let codes: [[u16; 3]; 4] = [
        [32768, 32768, 32768],
        [65535, 0, 0],
        [514, 514, 514],
        [515, 0, 0],
    ];
    write_png(
        &deep,
        &ImageBuffer::from_fn(4, 1, |x, _| Rgb(codes[x as usize])),
    );
    let d = read_ldr(&deep, &Response::Srgb).unwrap();
    assert_eq!(
        d.valid,
        [true, false, false, true],
        "top code and 2/255 of the range"
    );
    assert!(close(d.pixels[0].x, 0.214_048_202_298_185_2, 1e-6));
}

/// A JPEG (quality 90) of a grey field with a clipped white square in its middle.
fn jpeg_with_a_clipped_square(path: &Path) {
    let img = RgbImage::from_fn(32, 32, |x, y| {
        let inside = (12..20).contains(&x) && (12..20).contains(&y);
        Rgb(if inside { [255; 3] } else { [100, 90, 80] })
    });
    let f = std::fs::File::create(path).unwrap();
    let enc = ::image::codecs::jpeg::JpegEncoder::new_with_quality(f, 90);
    img.write_with_encoder(enc).unwrap();
}

#[test]
fn a_jpeg_masks_the_ring_around_its_clipped_area() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cam.jpg");
    jpeg_with_a_clipped_square(&p);
    let got = read_ldr(&p, &Response::Srgb).unwrap();
    assert_eq!((got.width, got.height), (32, 32));
    let at = |x: u32, y: u32| (y * 32 + x) as usize;
    // the square's inside and the pixel just outside its edge are masked ...
    for (x, y) in [(15, 15), (12, 12), (11, 15), (20, 15), (15, 11), (15, 20)] {
        assert!(!got.valid[at(x, y)], "({x}, {y}) should be masked");
    }
    // ... far from it the grey is read, within JPEG's error
    let want = response_lut(&Response::Srgb, 255)[90];
    for (x, y) in [(2, 2), (29, 3), (4, 28), (28, 28)] {
        assert!(got.valid[at(x, y)], "({x}, {y})");
        assert!(
            close(got.pixels[at(x, y)].y, want as f64, 0.05),
            "({x}, {y})"
        );
    }
    // the same picture as a PNG masks only the square itself
    let png = dir.path().join("cam.png");
    let dec = ::image::open(&p).unwrap().into_rgb8();
    dec.save(&png).unwrap();
    let clipped = dec.pixels().filter(|p| p.0.contains(&255)).count();
    assert_eq!(read_ldr(&png, &Response::Srgb).unwrap().masked, clipped);
    assert!(got.masked > clipped);
}

#[test]
fn a_grey_jpeg_is_read_as_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("grey.jpeg");
    ::image::GrayImage::from_pixel(16, 8, Luma([90]))
        .save(&p)
        .unwrap();
    let got = read_ldr(&p, &Response::Linear).unwrap();
    assert_eq!((got.width, got.height, got.masked), (16, 8, 0));
    for px in &got.pixels {
        assert_eq!(px.x, px.y);
        assert_eq!(px.y, px.z);
        assert!(close(px.x, 90.0 / 255.0, 0.02), "{px}");
    }
}

#[test]
fn malformed_files_are_refused_in_one_line_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let good_png = dir.path().join("good.png");
    write_png(&good_png, &RgbImage::from_pixel(16, 16, Rgb([1, 2, 3])));
    let png = std::fs::read(&good_png).unwrap();
    // a textured JPEG, so that its entropy-coded data is most of the file
    let good_jpg = dir.path().join("good.jpg");
    let texture = RgbImage::from_fn(64, 64, |x, y| Rgb([((x * 7) ^ (y * 13)) as u8, x as u8, 9]));
    texture.save(&good_jpg).unwrap();
    let jpg = std::fs::read(&good_jpg).unwrap();
    for (name, data) in [
        ("truncated.png", png[..png.len() / 2].to_vec()),
        ("garbage.png", b"not a png at all".to_vec()),
        ("empty.jpg", Vec::new()),
        ("garbage.jpeg", b"\xff\xd8 not a jpeg".to_vec()),
        ("png_inside.jpg", png.clone()),
        ("header_only.jpg", jpg[..200].to_vec()),
        ("truncated.jpg", jpg[..jpg.len() * 2 / 3].to_vec()),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, &data).unwrap();
        let e = read_ldr(&p, &Response::Srgb).unwrap_err();
        let s = e.to_string();
        assert_eq!(e.exit_code(), exit::INPUT, "{s}");
        assert!(
            s.starts_with(&format!("{}: not a readable ", p.display())),
            "{s}"
        );
        assert!(!s.contains('\n'), "{s}");
    }
    let e = read_ldr(&dir.path().join("missing.png"), &Response::Srgb).unwrap_err();
    assert_eq!(e.exit_code(), exit::MISSING);
    assert!(e.to_string().contains("missing.png"));
}
