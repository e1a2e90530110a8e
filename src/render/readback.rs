//! GPU buffers copied back to the CPU: offscreen frames and the renderer's check of its GPU blend.

use super::RenderError;

/// Maps a buffer, waits for the GPU and copies its bytes out.
pub(crate) fn read_buffer(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
) -> Result<Vec<u8>, RenderError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RenderError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| RenderError::Readback(e.to_string()))?
        .map_err(|e| RenderError::Readback(e.to_string()))?;
    let bytes = buffer
        .get_mapped_range(..)
        .map_err(|e| RenderError::Readback(format!("{e:?}")))?
        .to_vec();
    buffer.unmap();
    Ok(bytes)
}
