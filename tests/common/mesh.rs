//! Small test meshes.

use glam::Vec3;
use lipcall::render::head::{MorphDelta, Vertex};

/// An `n` x `n` grid of white vertices over the rectangle `[x0, x1, y0, y1]` at depth `z`,
/// facing +Z, as a triangle list.
pub fn grid([x0, x1, y0, y1]: [f32; 4], z: f32, n: usize) -> (Vec<Vertex>, Vec<u32>) {
    let mut vertices = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let x = x0 + (x1 - x0) * i as f32 / (n - 1) as f32;
            let y = y0 + (y1 - y0) * j as f32 / (n - 1) as f32;
            vertices.push(Vertex {
                position: [x, y, z],
                normal: [0.0, 0.0, 1.0],
                uv: [0.0; 2],
                color: [1.0; 4],
            });
        }
    }
    let mut indices = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = (j * n + i) as u32;
            let n = n as u32;
            indices.extend_from_slice(&[a, a + 1, a + n + 1, a, a + n + 1, a + n]);
        }
    }
    (vertices, indices)
}

/// Morph deltas moving each of `vertices` by `f(position)` (normals unchanged).
pub fn deltas(vertices: &[Vertex], f: impl Fn(Vec3) -> Vec3) -> Vec<MorphDelta> {
    vertices
        .iter()
        .map(|v| MorphDelta {
            position: f(Vec3::from(v.position)).into(),
            normal: [0.0; 3],
        })
        .collect()
}
