//! The file's buffers: the GLB binary chunk, base64 `data:` URIs and files beside the head,
//! and the byte range of a buffer view.

use std::path::Path;

use crate::render::RenderError;

pub(super) fn load_buffers(
    doc: &gltf::Document,
    blob: Option<&[u8]>,
    base: Option<&Path>,
) -> Result<Vec<Vec<u8>>, RenderError> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => blob
                .ok_or_else(|| RenderError::Gltf("GLB binary chunk missing".into()))?
                .to_vec(),
            gltf::buffer::Source::Uri(uri) => read_uri(uri, base)?,
        };
        if data.len() < buffer.length() {
            return Err(RenderError::Gltf(format!(
                "buffer {} has {} bytes, declares {}",
                buffer.index(),
                data.len(),
                buffer.length()
            )));
        }
        out.push(data);
    }
    Ok(out)
}

pub(super) fn read_uri(uri: &str, base: Option<&Path>) -> Result<Vec<u8>, RenderError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest
            .split_once(";base64,")
            .ok_or_else(|| RenderError::Unsupported("data URI that is not base64".into()))?;
        return decode_base64(payload);
    }
    let base = base.ok_or_else(|| {
        RenderError::Unsupported(format!("external resource {uri:?} without a file path"))
    })?;
    if uri.contains("..") || uri.contains("://") || uri.starts_with('/') {
        return Err(RenderError::Unsupported(format!("resource path {uri:?}")));
    }
    let path = base.join(uri.replace("%20", " "));
    Ok(crate::input::read(&path, crate::input::MAX_INPUT_BYTES)?)
}

fn decode_base64(s: &str) -> Result<Vec<u8>, RenderError> {
    let value = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => return None,
        } as u32)
    };
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    for &c in s.as_bytes() {
        if c == b'=' || c.is_ascii_whitespace() {
            continue;
        }
        let v = value(c).ok_or_else(|| RenderError::Gltf("bad base64 in data URI".into()))?;
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

pub(super) fn view_slice<'a>(
    view: &gltf::buffer::View,
    buffers: &'a [Vec<u8>],
) -> Result<&'a [u8], RenderError> {
    let data = buffers
        .get(view.buffer().index())
        .ok_or_else(|| RenderError::Gltf("buffer view of a missing buffer".into()))?;
    let end = view
        .offset()
        .checked_add(view.length())
        .ok_or_else(|| RenderError::Gltf("buffer view overflows".into()))?;
    data.get(view.offset()..end)
        .ok_or_else(|| RenderError::Gltf(format!("buffer view {} out of range", view.index())))
}
