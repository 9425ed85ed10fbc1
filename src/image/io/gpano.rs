//! The Photo Sphere (GPano) XMP properties of a JPEG panorama: its projection
//! and, for a cropped panorama, which part of the full sphere it holds. Cameras
//! and stitchers write them; lumiprobe reads every frame as a full
//! equirectangular sphere, so a frame that says otherwise is noted.

use std::path::Path;

/// What a JPEG's GPano XMP says of it (absent properties are `None`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GPano {
    /// `GPano:ProjectionType` (`equirectangular` for a sphere).
    pub projection: Option<String>,
    /// `GPano:FullPanoWidthPixels` x `FullPanoHeightPixels`.
    pub full: Option<(u64, u64)>,
    /// `GPano:CroppedAreaImageWidthPixels` x `CroppedAreaImageHeightPixels`.
    pub cropped: Option<(u64, u64)>,
}

/// Bytes of a file read for its metadata at most: the XMP segment of a JPEG
/// sits in its first 64 KiB segments, before the image data.
const HEAD: u64 = 1 << 18;

/// The value of property `name` (`GPano:Name`) in XMP text, written as an
/// attribute (`GPano:Name="v"`) or an element (`<GPano:Name>v</GPano:Name>`).
fn property(xmp: &str, name: &str) -> Option<String> {
    let attr = format!("GPano:{name}=");
    if let Some(i) = xmp.find(&attr) {
        let rest = &xmp[i + attr.len()..];
        let q = rest.chars().next()?;
        if q == '"' || q == '\'' {
            let v = &rest[1..];
            return v.find(q).map(|e| v[..e].trim().to_string());
        }
    }
    let open = format!("<GPano:{name}>");
    let i = xmp.find(&open)?;
    let rest = &xmp[i + open.len()..];
    rest.find('<').map(|e| rest[..e].trim().to_string())
}

/// The GPano properties of JPEG `bytes`, from its XMP segment (APP1 with the
/// `http://ns.adobe.com/xap/1.0/` header); `None` when it has none.
pub fn parse(bytes: &[u8]) -> Option<GPano> {
    const XMP: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
    if !bytes.starts_with(&[0xff, 0xd8]) {
        return None;
    }
    let mut pos = 2usize;
    while pos + 4 <= bytes.len() && bytes[pos] == 0xff {
        let marker = bytes[pos + 1];
        if marker == 0xda || marker == 0xd9 {
            break;
        }
        let len = u16::from_be_bytes([bytes[pos + 2], bytes[pos + 3]]) as usize;
        let body = bytes.get(pos + 4..pos + 2 + len.max(2))?;
        if marker == 0xe1 && body.starts_with(XMP) {
            let xmp = String::from_utf8_lossy(&body[XMP.len()..]);
            if !xmp.contains("GPano:") {
                return None;
            }
            let num = |n: &str| property(&xmp, n).and_then(|v| v.parse::<u64>().ok());
            let pair = |a: &str, b: &str| Some((num(a)?, num(b)?));
            return Some(GPano {
                projection: property(&xmp, "ProjectionType"),
                full: pair("FullPanoWidthPixels", "FullPanoHeightPixels"),
                cropped: pair(
                    "CroppedAreaImageWidthPixels",
                    "CroppedAreaImageHeightPixels",
                ),
            });
        }
        pos += 2 + len;
    }
    None
}

/// A note for a frame whose GPano XMP says it is not a full equirectangular
/// sphere (another projection, or a crop of one); `None` otherwise, and for a
/// file that cannot be read (its reader will say why).
pub fn note(path: &Path) -> Option<String> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(HEAD)
        .read_to_end(&mut head)
        .ok()?;
    let g = parse(&head)?;
    if let Some(p) = &g.projection {
        if !p.eq_ignore_ascii_case("equirectangular") {
            return Some(format!(
                "{}: its Photo Sphere metadata declares a {p:?} projection; lumiprobe reads \
                 frames as equirectangular panoramas (convert it first)",
                path.display()
            ));
        }
    }
    match (g.cropped, g.full) {
        (Some(c), Some(f)) if c != f => Some(format!(
            "{}: its Photo Sphere metadata declares a cropped panorama ({}x{} of a full \
             {}x{} sphere); lumiprobe reads it as the full sphere (pad it to the full size \
             first)",
            path.display(),
            c.0,
            c.1,
            f.0,
            f.1
        )),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jpeg_with_xmp(xmp: &str) -> Vec<u8> {
        let mut body = b"http://ns.adobe.com/xap/1.0/\0".to_vec();
        body.extend_from_slice(xmp.as_bytes());
        let mut j = vec![0xff, 0xd8, 0xff, 0xe1];
        j.extend_from_slice(&((body.len() + 2) as u16).to_be_bytes());
        j.extend_from_slice(&body);
        j.extend_from_slice(&[0xff, 0xda, 0x00, 0x02, 0xff, 0xd9]);
        j
    }

    #[test]
    fn gpano_attributes_and_elements_are_read_and_crops_noted() {
        let full = jpeg_with_xmp(
            r#"<x:xmpmeta><rdf:Description GPano:ProjectionType="equirectangular"
               GPano:FullPanoWidthPixels="4096" GPano:FullPanoHeightPixels="2048"
               GPano:CroppedAreaImageWidthPixels="4096" GPano:CroppedAreaImageHeightPixels="2048"/></x:xmpmeta>"#,
        );
        let g = parse(&full).unwrap();
        assert_eq!(g.projection.as_deref(), Some("equirectangular"));
        assert_eq!(
            (g.full, g.cropped),
            (Some((4096, 2048)), Some((4096, 2048)))
        );
        let cropped = jpeg_with_xmp(
            "<GPano:ProjectionType>equirectangular</GPano:ProjectionType>\
             <GPano:FullPanoWidthPixels>8000</GPano:FullPanoWidthPixels>\
             <GPano:FullPanoHeightPixels>4000</GPano:FullPanoHeightPixels>\
             <GPano:CroppedAreaImageWidthPixels>8000</GPano:CroppedAreaImageWidthPixels>\
             <GPano:CroppedAreaImageHeightPixels>2000</GPano:CroppedAreaImageHeightPixels>",
        );
        assert_eq!(parse(&cropped).unwrap().cropped, Some((8000, 2000)));
        let cyl = jpeg_with_xmp(r#"<d GPano:ProjectionType='cylindrical'/>"#);
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes, says) in [
            ("full.jpg", &full, None),
            ("crop.jpg", &cropped, Some("8000x2000 of a full 8000x4000")),
            ("cyl.jpg", &cyl, Some("\"cylindrical\" projection")),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            let n = note(&p);
            match says {
                None => assert_eq!(n, None),
                Some(s) => {
                    let n = n.unwrap();
                    assert!(n.contains(s) && n.contains(name), "{n}");
                }
            }
        }
        // No XMP, not a JPEG, truncated: nothing, and no panic.
        assert_eq!(parse(&[0xff, 0xd8, 0xff, 0xda, 0, 2]), None);
        assert_eq!(parse(b"GIF89a"), None);
        for cut in 0..cropped.len() {
            let _ = parse(&cropped[..cut]);
        }
        assert_eq!(note(&dir.path().join("missing.jpg")), None);
    }
}
