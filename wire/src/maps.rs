//! Maps on the wire: a map folder or shipped map as a [`MapBundle`], and the checks of
//! what a received bundle's files say.

use paddock_proto::{Error, ErrorCode, MapBundle, MapFile, MapRef, error};
use paddock_sim::circuit::{Circuit, CircuitSource, Circuits};
use paddock_sim::shipped::ShippedMap;

/// The bundle of a map name or directory (as [`paddock_rollout::Scenario::map`] holds
/// it) as `circuits` finds it: every file, the content hash and the name the client
/// used.
pub fn local_map(circuits: &Circuits, map: &str) -> Result<MapBundle, Error> {
    let circuit = circuits
        .get(map)
        .map_err(|e| error(ErrorCode::NotFound, "map", format!("map {map:?}: {e}")))?;
    let bundle = circuit_bundle(&circuit, map)?;
    // what the broker and workers will check: refuse here, before sending
    check_map_bundle(&bundle).map_err(|mut e| {
        e.message = format!("map {map:?} ({}): {}", where_from(&circuit), e.message);
        e
    })?;
    Ok(bundle)
}

/// Where a circuit's files are, for messages.
fn where_from(circuit: &Circuit) -> String {
    match &circuit.source {
        CircuitSource::Dir(d) => format!("in {}", d.display()),
        CircuitSource::Shipped(m) => format!("shipped map {}", m.name),
        CircuitSource::Memory => "built in memory".into(),
    }
}

/// The bundle of a loaded circuit's files, named `name`: its folder's files, or the
/// embedded files of a shipped map (no disk access).
pub fn circuit_bundle(circuit: &Circuit, name: &str) -> Result<MapBundle, Error> {
    match &circuit.source {
        CircuitSource::Dir(dir) => paddock_proto::read_map_dir(dir, name).map_err(|e| {
            error(
                ErrorCode::Internal,
                "map",
                format!("reading map {name:?} from {}: {e}", dir.display()),
            )
        }),
        CircuitSource::Shipped(m) => Ok(shipped_bundle(m, name)),
        CircuitSource::Memory => Err(error(
            ErrorCode::InvalidArgument,
            "map",
            format!(
                "map {name:?} was built in memory: it has no files to send (save it to a folder)"
            ),
        )),
    }
}

fn shipped_bundle(m: &ShippedMap, name: &str) -> MapBundle {
    let files: Vec<MapFile> = m
        .files
        .iter()
        .map(|(file, data)| MapFile {
            name: file.to_string(),
            data: data.to_vec(),
        })
        .collect();
    MapBundle {
        hash: paddock_proto::bundle_hash(&files),
        name: name.to_string(),
        files,
    }
}

/// The bundles of the maps shipped inside the binary ([`paddock_sim::shipped`]), each
/// named by its map name; the same bundles as [`paddock_proto::read_map_dir`] makes of
/// the project's map folders.
pub fn shipped_bundles() -> Vec<MapBundle> {
    paddock_sim::shipped::shipped_maps()
        .iter()
        .map(|m| shipped_bundle(m, m.name))
        .collect()
}

/// The [`MapRef`] naming a bundle.
pub fn map_ref(bundle: &MapBundle) -> MapRef {
    MapRef {
        name: bundle.name.clone(),
        hash: bundle.hash.clone(),
    }
}

/// Checks a received bundle: its form ([`paddock_proto::check_bundle`]: bare file
/// names, size, hash) and that it is self-contained: each map YAML's `image:` must be a
/// bare name of a file in the bundle (never a path: nothing outside the bundle is
/// opened, so a client cannot probe the host's files), and each image's header must
/// claim a size within the caps of [`paddock_sim::map::image_dimensions`]. Only headers
/// are read, so this is cheap; the pixels are decoded by the worker that loads the map.
pub fn check_map_bundle(bundle: &MapBundle) -> Result<(), Error> {
    paddock_proto::check_bundle(bundle)?;
    for (i, f) in bundle.files.iter().enumerate() {
        if !(f.name.ends_with(".yaml") || f.name.ends_with(".yml")) {
            continue;
        }
        let Ok(text) = std::str::from_utf8(&f.data) else {
            continue;
        };
        let field = format!("map_bundle.files[{i}].image");
        let image = match paddock_sim::map::bundle_image_name(text) {
            Ok(Some(name)) => name,
            Ok(None) => continue,
            Err(reason) => return Err(error(ErrorCode::InvalidArgument, field, reason)),
        };
        let Some((j, img)) = bundle
            .files
            .iter()
            .enumerate()
            .find(|(_, g)| g.name == image)
        else {
            return Err(error(
                ErrorCode::InvalidArgument,
                field,
                format!("{image:?} is not a file of the bundle"),
            ));
        };
        paddock_sim::map::image_dimensions(&img.data).map_err(|reason| {
            let code = if reason.contains("exceeds the limit") {
                ErrorCode::TooLarge
            } else {
                ErrorCode::InvalidArgument
            };
            error(
                code,
                format!("map_bundle.files[{j}].data"),
                format!("map image {image:?}: {reason}"),
            )
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_bundles_are_the_project_map_folders() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../maps");
        let bundles = shipped_bundles();
        let circuits = Circuits::new();
        assert!(bundles.len() >= 3);
        for b in &bundles {
            check_map_bundle(b).unwrap();
            let folder = paddock_proto::read_map_dir(&root.join(&b.name), &b.name).unwrap();
            assert_eq!(b.files, folder.files, "{}", b.name);
            assert_eq!(b.hash, folder.hash, "{}", b.name);
            // and a name resolves to the same bundle
            assert_eq!(local_map(&circuits, &b.name).unwrap().hash, b.hash);
            // and the project's folder given as a path
            let dir = root.join(&b.name).display().to_string();
            assert_eq!(local_map(&circuits, &dir).unwrap().hash, b.hash);
        }
        assert!(local_map(&circuits, "no-such-map-anywhere").is_err());
    }

    fn map_bundle(yaml: &str, image: (&str, Vec<u8>)) -> MapBundle {
        let files = vec![
            MapFile {
                name: "m_map.yaml".into(),
                data: yaml.as_bytes().to_vec(),
            },
            MapFile {
                name: image.0.into(),
                data: image.1,
            },
        ];
        MapBundle {
            hash: paddock_proto::bundle_hash(&files),
            name: "m".into(),
            files,
        }
    }

    fn yaml(image: &str) -> String {
        format!("image: {image}\nresolution: 0.05\norigin: [0, 0, 0]\n")
    }

    /// A client's bundle could name any host file as its image, and the different errors
    /// for existing, missing and directory paths told the client which exist.
    #[test]
    fn bundle_image_paths_outside_the_bundle_are_refused_without_opening_them() {
        let png = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../maps/lakeside/lakeside_map.png"
        ))
        .unwrap();
        check_map_bundle(&map_bundle(&yaml("m_map.png"), ("m_map.png", png.clone()))).unwrap();
        let mut messages = Vec::new();
        for bad in [
            "/etc/passwd",
            "/nonexistent/x.png",
            "/tmp",
            "../m_map.png",
            "../../etc/hosts",
        ] {
            let e =
                check_map_bundle(&map_bundle(&yaml(bad), ("m_map.png", png.clone()))).unwrap_err();
            assert_eq!(e.field, "map_bundle.files[0].image", "{bad}: {e:?}");
            assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
            assert!(e.message.contains(bad), "{bad}: {}", e.message);
            messages.push(e.message.replace(bad, "PATH"));
        }
        // the same answer whether the path exists, is missing or is a directory
        messages.dedup();
        assert_eq!(messages.len(), 1, "{messages:?}");
        // a bare name that is not in the bundle
        let e = check_map_bundle(&map_bundle(&yaml("other.png"), ("m_map.png", png))).unwrap_err();
        assert_eq!(e.field, "map_bundle.files[0].image");
        assert!(
            e.message.contains("not a file of the bundle"),
            "{}",
            e.message
        );
    }

    #[test]
    fn bundle_images_above_the_size_cap_are_refused_from_the_header() {
        // a PNG header claiming 20000 x 20000 pixels, then a token of image data
        fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = out.len();
            out.extend_from_slice(kind);
            out.extend_from_slice(data);
            let mut crc = !0u32;
            for &b in &out[start..] {
                crc ^= u32::from(b);
                for _ in 0..8 {
                    crc = if crc & 1 == 1 {
                        (crc >> 1) ^ 0xEDB8_8320
                    } else {
                        crc >> 1
                    };
                }
            }
            out.extend_from_slice(&(!crc).to_be_bytes());
        }
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut ihdr = 20_000u32.to_be_bytes().repeat(2);
        ihdr.extend_from_slice(&[8, 0, 0, 0, 0]);
        chunk(&mut png, b"IHDR", &ihdr);
        chunk(
            &mut png,
            b"IDAT",
            &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
        );
        chunk(&mut png, b"IEND", &[]);
        let e = check_map_bundle(&map_bundle(&yaml("m_map.png"), ("m_map.png", png))).unwrap_err();
        assert_eq!(e.field, "map_bundle.files[1].data");
        assert_eq!(e.code, ErrorCode::TooLarge as i32);
        assert!(e.message.contains("20000 x 20000"), "{}", e.message);
    }
}
