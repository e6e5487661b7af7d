//! Map images are data with a size cap: the header is read first and an image above
//! `MAX_IMAGE_SIDE` / `MAX_IMAGE_PIXELS` is refused before any pixel is allocated (a
//! 20000 x 20000 PNG once blocked a broker 16.5 s at 2.4 GB); real maps decode exactly as
//! before; a bundle's `image:` must be a bare file name.

mod common;

use std::path::{Path, PathBuf};

use paddock_sim::map::{
    MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, Map, bundle_image_name, decode_image, image_dimensions,
};

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A valid-looking 8-bit grey PNG that claims `w` x `h` pixels, with a few bytes of
/// image data: what a hostile client sends (a real one compresses to ~439 KB).
fn claimed_png(w: u32, h: u32) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit grey, deflate, no filter/interlace
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    chunk(&mut png, b"IEND", &[]);
    png
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("paddock-map-limits-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_20000_square_png_is_refused_from_its_header() {
    let png = claimed_png(20_000, 20_000);
    let e = image_dimensions(&png).unwrap_err();
    assert!(e.contains("20000 x 20000") && e.contains("exceeds"), "{e}");
    let e = decode_image(&png).unwrap_err();
    assert!(e.contains("20000 x 20000"), "{e}");
    // through the map loader too, naming the image and the size
    let d = temp_dir("huge");
    std::fs::write(d.join("huge.png"), &png).unwrap();
    std::fs::write(
        d.join("huge.yaml"),
        "image: huge.png\nresolution: 0.05\norigin: [0, 0, 0]\n",
    )
    .unwrap();
    let e = Map::load(&d.join("huge.yaml")).unwrap_err().to_string();
    assert!(e.contains("huge.png") && e.contains("20000 x 20000"), "{e}");
    // each cap on its own: one side too long, too many pixels with both sides allowed
    assert!(image_dimensions(&claimed_png(MAX_IMAGE_SIDE + 1, 10)).is_err());
    let side = MAX_IMAGE_SIDE;
    assert!(u64::from(side) * u64::from(side) > MAX_IMAGE_PIXELS);
    assert!(image_dimensions(&claimed_png(side, side)).is_err());
    assert_eq!(
        image_dimensions(&claimed_png(4000, 3000)).unwrap(),
        (4000, 3000)
    );
}

#[test]
fn bundle_images_must_be_bare_names() {
    let yaml = |image: &str| format!("image: {image}\nresolution: 0.05\norigin: [0, 0, 0]\n");
    assert_eq!(
        bundle_image_name(&yaml("track.png")).unwrap().as_deref(),
        Some("track.png")
    );
    for bad in [
        "/etc/passwd",
        "../secret.png",
        "maps/../../x.png",
        "sub/track.png",
        "..",
    ] {
        let e = bundle_image_name(&yaml(bad)).unwrap_err();
        assert!(
            e.contains(bad) && e.contains("not a bare file name"),
            "{bad}: {e}"
        );
    }
    // not a map YAML: nothing to check
    assert_eq!(bundle_image_name("speed: 3\n").unwrap(), None);
}

fn map_images() -> Vec<PathBuf> {
    let mut roots = vec![Path::new(env!("CARGO_MANIFEST_DIR")).join("../maps")];
    roots.extend(common::shared("maps"));
    let mut images = Vec::new();
    for root in roots {
        for dir in std::fs::read_dir(root).unwrap().flatten() {
            if !dir.path().is_dir() {
                continue;
            }
            for f in std::fs::read_dir(dir.path()).unwrap().flatten() {
                let p = f.path();
                if matches!(p.extension().and_then(|e| e.to_str()), Some("png" | "pgm")) {
                    images.push(p);
                }
            }
        }
    }
    images.sort();
    images
}

/// The capped decoder gives exactly the pixels of the plain one on every real map, so
/// maps built from them (and their content hashes) are unchanged.
#[test]
fn real_maps_decode_exactly_as_before() {
    let images = map_images();
    assert!(images.len() >= 3, "{images:?}");
    for p in &images {
        let bytes = std::fs::read(p).unwrap();
        let capped = decode_image(&bytes).unwrap();
        let plain = image::load_from_memory(&bytes).unwrap().into_luma8();
        assert_eq!(capped.dimensions(), plain.dimensions(), "{}", p.display());
        assert!(
            capped.as_raw() == plain.as_raw(),
            "{} decodes differently",
            p.display()
        );
    }
}
