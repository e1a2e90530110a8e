//! Materials: base colour factors and PNG or JPEG base colour textures, decoded within limits
//! on their size; a texture that cannot be used leaves its material the base colour factor.

use std::path::Path;

use super::buffers::{read_uri, view_slice};
use crate::render::head::{Material, Texture};

/// Largest base colour texture side accepted; larger ones are refused before any pixel is decoded.
pub(super) const MAX_TEXTURE_SIDE: u32 = 8192;
/// Pixels of all textures decoded together: each material decodes its own, so one small,
/// highly compressed image behind many materials would otherwise be decoded for each.
pub(super) const MAX_TEXTURE_PIXELS: u64 = 8192 * 8192;

/// The document's materials, decoding textures until `texture_pixels` are spent (later ones
/// keep their base colour factor).
pub(super) fn load_materials(
    doc: &gltf::Document,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    mut texture_pixels: u64,
) -> Vec<Material> {
    doc.materials()
        .map(|m| load_material(doc, &m, buffers, base, &mut texture_pixels))
        .collect()
}

fn load_material(
    doc: &gltf::Document,
    m: &gltf::Material,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    texture_pixels: &mut u64,
) -> Material {
    let name = m.name().unwrap_or("material").to_owned();
    let pbr = m.pbr_metallic_roughness();
    let factor = pbr.base_color_factor();
    // A texture that cannot be used is not fatal: the material keeps its base colour factor.
    let texture = pbr.base_color_texture().and_then(|info| {
        let image = info.texture().source().index();
        match load_texture(doc, image, buffers, base, texture_pixels) {
            Ok(texture) => Some(texture),
            Err(reason) => {
                tracing::warn!(
                    "material {name:?}: base colour texture (image {image}) not used, \
                     drawn with its base colour factor: {reason}"
                );
                None
            }
        }
    });
    Material {
        name,
        base_color: factor.map(|c| {
            if c.is_finite() {
                c.clamp(0.0, 1.0)
            } else {
                1.0
            }
        }),
        texture,
        double_sided: m.double_sided(),
    }
}

/// Reads and decodes image `index` of the document as RGBA8, or says why it cannot.
fn load_texture(
    doc: &gltf::Document,
    index: usize,
    buffers: &[Vec<u8>],
    base: Option<&Path>,
    texture_pixels: &mut u64,
) -> Result<Texture, String> {
    // Read from the JSON: `gltf::Image::source` panics on an image with a buffer view and no
    // MIME type, or with neither a buffer view nor a URI.
    let json = doc.as_json().images.get(index).ok_or("no such image")?;
    let mime = json.mime_type.as_ref().map(|m| m.0.as_str());
    let bytes = if let Some(view) = &json.buffer_view {
        let view = doc
            .views()
            .nth(view.value())
            .ok_or("buffer view out of range")?;
        view_slice(&view, buffers)
            .map_err(|e| e.to_string())?
            .to_vec()
    } else if let Some(uri) = &json.uri {
        read_uri(uri, base).map_err(|e| e.to_string())?
    } else {
        return Err("the image has neither a buffer view nor a URI".into());
    };
    let format = texture_format(mime, &bytes).ok_or_else(|| match mime {
        Some(m) => format!("unsupported image type {m:?} (PNG and JPEG are)"),
        None => "not a PNG or JPEG image".to_owned(),
    })?;
    let (width, height) = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format)
        .into_dimensions()
        .map_err(|e| format!("{format:?} image does not decode: {e}"))?;
    *texture_pixels = texture_pixels
        .checked_sub(u64::from(width) * u64::from(height))
        .ok_or_else(|| {
            format!("the head's textures together would exceed {MAX_TEXTURE_PIXELS} pixels")
        })?;
    decode_texture(&bytes, format)
}

/// Decodes PNG or JPEG bytes as RGBA8, refusing declared sizes over [`MAX_TEXTURE_SIDE`] before
/// allocating for the pixels.
fn decode_texture(bytes: &[u8], format: image::ImageFormat) -> Result<Texture, String> {
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    reader.limits(limits);
    let decoded = reader
        .decode()
        .map_err(|e| format!("{format:?} image does not decode: {e}"))?;
    let rgba = decoded.to_rgba8();
    Ok(Texture {
        width: rgba.width(),
        height: rgba.height(),
        rgba: rgba.into_raw(),
    })
}

/// The format to decode a texture as: its declared MIME type when it has one, else the bytes'
/// signature. `None` for anything but PNG and JPEG.
fn texture_format(mime: Option<&str>, bytes: &[u8]) -> Option<image::ImageFormat> {
    match mime {
        Some(m) => match m.trim().to_ascii_lowercase().as_str() {
            "image/png" => Some(image::ImageFormat::Png),
            "image/jpeg" | "image/jpg" => Some(image::ImageFormat::Jpeg),
            _ => None,
        },
        None if bytes.starts_with(b"\x89PNG\r\n\x1a\n") => Some(image::ImageFormat::Png),
        None if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) => Some(image::ImageFormat::Jpeg),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::super::buffers::load_buffers;
    use super::{decode_texture, load_materials, texture_format};
    use image::ImageFormat;

    const PNG: &[u8] = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR";
    const JPEG: &[u8] = &[0xFF, 0xD8, 0xFF, 0xE0, 0, 16, b'J', b'F', b'I', b'F'];

    #[test]
    fn declared_mime_type_wins_over_the_signature() {
        assert_eq!(
            texture_format(Some("image/jpeg"), PNG),
            Some(ImageFormat::Jpeg)
        );
        assert_eq!(
            texture_format(Some("image/png"), JPEG),
            Some(ImageFormat::Png)
        );
        assert_eq!(texture_format(Some("image/webp"), PNG), None);
        assert_eq!(texture_format(Some("image/ktx2"), JPEG), None);
    }

    #[test]
    fn signature_decides_without_a_mime_type() {
        assert_eq!(texture_format(None, PNG), Some(ImageFormat::Png));
        assert_eq!(texture_format(None, JPEG), Some(ImageFormat::Jpeg));
        assert_eq!(texture_format(None, b"RIFF\0\0\0\0WEBPVP8 "), None);
        assert_eq!(texture_format(None, b""), None);
    }

    #[test]
    fn oversized_textures_are_refused_before_decoding() {
        let img = image::RgbImage::from_pixel(8, 8, image::Rgb([0, 0, 255]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
            .encode_image(&img)
            .unwrap();
        let ok = decode_texture(&jpeg, ImageFormat::Jpeg).unwrap();
        assert_eq!((ok.width, ok.height), (8, 8));
        // Declare 60000 x 60000 in the frame header (SOF0: FF C0, length, precision, height, width).
        let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
        jpeg[sof + 5..sof + 9].copy_from_slice(&[0xEA, 0x60, 0xEA, 0x60]);
        let err = decode_texture(&jpeg, ImageFormat::Jpeg).unwrap_err();
        assert!(err.to_lowercase().contains("limit"), "{err}");
    }

    #[test]
    fn one_image_behind_many_materials_is_decoded_within_the_pixel_budget() {
        let img = image::RgbaImage::from_pixel(16, 16, image::Rgba([200, 100, 50, 255]));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), ImageFormat::Png)
            .unwrap();
        // A data URI in base64, as exporters write it.
        const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut b64 = String::new();
        for chunk in png.chunks(3) {
            let n = chunk
                .iter()
                .enumerate()
                .fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
            for k in 0..4 {
                b64.push(if k <= chunk.len() {
                    ABC[(n >> (18 - 6 * k) & 63) as usize] as char
                } else {
                    '='
                });
            }
        }
        let materials = [r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#; 5];
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}],
            "bufferViews":[{{"buffer":0,"byteLength":{}}}],
            "images":[{{"bufferView":0,"mimeType":"image/png"}}],
            "textures":[{{"source":0}}],
            "materials":[{}]}}"#,
            png.len(),
            png.len(),
            materials.join(",")
        );
        let gltf = gltf::Gltf::from_slice(json.as_bytes()).unwrap();
        let buffers = load_buffers(&gltf.document, None, None).unwrap();
        let loaded = load_materials(&gltf.document, &buffers, None, 2 * 16 * 16);
        let textured: Vec<bool> = loaded.iter().map(|m| m.texture.is_some()).collect();
        assert_eq!(textured, [true, true, false, false, false]);
        let all = load_materials(&gltf.document, &buffers, None, 5 * 16 * 16);
        assert!(all.iter().all(|m| m.texture.is_some()));
    }
}
