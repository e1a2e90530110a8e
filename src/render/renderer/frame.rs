//! Per frame: each head instance's uniforms (camera, placement, look, the 20 slots' weights)
//! written only when they change, and its draws recorded into a render pass.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};

use super::GpuHead;
use super::pipelines::{HeadRenderer, Shading};
use crate::render::camera::Camera;
use crate::render::head::{TARGET_COUNT, slot_weights};
use crate::render::variant::{HeadVariant, LookUniform};
use crate::vocab::VISEME_COUNT;
use crate::vocab::{FacePose, VisemeWeights};

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct ViewUniform {
    view_proj: [[f32; 4]; 4],
    model: [[f32; 4]; 4],
    eye: [f32; 4],
    light_dir: [f32; 4],
    counts: [u32; 4],
    look: LookUniform,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct WeightsUniform {
    /// x: how many slots carry weight; the first `x` entries of `slots` and `w` are they, so the
    /// vertex stage loops over those alone. y: how many of them are visemes (they come first).
    active: [u32; 4],
    slots: [u32; TARGET_COUNT],
    w: [f32; TARGET_COUNT],
}

impl WeightsUniform {
    fn new(weights: &VisemeWeights, pose: &FacePose) -> Self {
        let mut u = Self {
            active: [0; 4],
            slots: [0; TARGET_COUNT],
            w: [0.0; TARGET_COUNT],
        };
        let mut n = 0;
        for (slot, w) in slot_weights(weights, pose).into_iter().enumerate() {
            if slot == VISEME_COUNT {
                u.active[1] = n as u32;
            }
            if w != 0.0 {
                u.slots[n] = slot as u32;
                u.w[n] = w;
                n += 1;
            }
        }
        u.active[0] = n as u32;
        u
    }
}

/// One head on screen: its own uniforms (camera, placement, weights) over a shared [`GpuHead`].
pub struct HeadInstance {
    pub(super) head: Arc<GpuHead>,
    view_buffer: wgpu::Buffer,
    weights_buffer: wgpu::Buffer,
    pub(super) bind_group: wgpu::BindGroup,
    last_view: Option<ViewUniform>,
    last_weights: Option<WeightsUniform>,
    /// Placement of the head in the scene (rotation, uniform scale, translation).
    pub model: Mat4,
    /// Level of detail drawn (0, the full mesh, unless the head was uploaded with levels; see
    /// [`GpuHead::level_for`]).
    pub level: usize,
    /// Where lighting is computed ([`GpuHead::shading_for`]).
    pub shading: Shading,
    /// Whether to leave out the triangles a frontal camera cannot see
    /// ([`crate::render::facing`]) where this frame's camera and pose allow (on by default).
    pub leave_out_unseen: bool,
    /// Whether this frame's draws are the frontal ones (set by `prepare`).
    frontal: bool,
    /// The look drawn: skin, hair and face shape ([`HeadVariant::DEFAULT`]: the head as it is).
    pub variant: HeadVariant,
}

impl HeadInstance {
    pub fn head(&self) -> &Arc<GpuHead> {
        &self.head
    }

    /// Triangles drawn by this frame's `paint` (before culling).
    pub fn triangles_drawn(&self) -> usize {
        let level = self.head.level(self.level);
        if self.frontal {
            level.frontal_triangles
        } else {
            level.triangles
        }
    }
}

impl HeadRenderer {
    /// Creates the per-head uniforms for drawing `head` (many instances may share one head).
    pub fn new_instance(
        &self,
        device: &wgpu::Device,
        head: Arc<GpuHead>,
        label: &str,
    ) -> HeadInstance {
        let view_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(&format!("{label} view uniform")),
            size: std::mem::size_of::<ViewUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let weights_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(&format!("{label} target weights")),
            size: std::mem::size_of::<WeightsUniform>() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&format!("{label} bind group")),
            layout: &self.head_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: view_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: weights_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: head.delta_buffer.as_entire_binding(),
                },
            ],
        });
        HeadInstance {
            head,
            view_buffer,
            weights_buffer,
            bind_group,
            last_view: None,
            last_weights: None,
            model: Mat4::IDENTITY,
            level: 0,
            shading: Shading::PerPixel,
            leave_out_unseen: true,
            frontal: false,
            variant: HeadVariant::DEFAULT,
        }
    }

    /// Writes this frame's uniforms: the weights of the 20 slots (the 15 visemes and the pose's
    /// eyes) and, only when the camera, aspect, placement or head rotation changed, the view.
    /// The pose's head rotation turns the head about its neck pivot
    /// ([`FaceFrame::neck_pivot`]) on top of `instance.model`. Call before the render pass is
    /// begun.
    ///
    /// [`FaceFrame::neck_pivot`]: crate::render::head::FaceFrame::neck_pivot
    pub fn prepare(
        &self,
        queue: &wgpu::Queue,
        instance: &mut HeadInstance,
        camera: &Camera,
        aspect: f32,
        weights: &VisemeWeights,
        pose: &FacePose,
    ) {
        let light = Vec3::new(-0.45, -0.55, -0.7).normalize();
        let model = instance.model * pose.head_matrix(instance.head.frame.neck_pivot());
        let view = ViewUniform {
            view_proj: camera.view_proj(aspect).to_cols_array_2d(),
            model: model.to_cols_array_2d(),
            eye: camera.eye.extend(1.0).into(),
            light_dir: light.extend(0.0).into(),
            counts: [
                instance.head.morph_vertices,
                instance.head.vertex_count,
                instance.head.mouth_and_eyes_from,
                instance.head.eyes_only_from,
            ],
            look: instance.variant.look(instance.head.frame.neck_pivot()),
        };
        if instance.last_view != Some(view) {
            queue.write_buffer(&instance.view_buffer, 0, bytemuck::bytes_of(&view));
            instance.last_view = Some(view);
        }
        let head = &instance.head;
        let tolerance = 1e-3 * head.frame.mouth_width.max(1e-4);
        instance.frontal = instance.leave_out_unseen
            && instance.model == Mat4::IDENTITY
            && pose.head_within_bounds()
            && head
                .frontal_eyes
                .iter()
                .any(|e| e.distance(camera.eye) <= tolerance);
        let w = WeightsUniform::new(weights, pose);
        if instance.last_weights != Some(w) {
            queue.write_buffer(&instance.weights_buffer, 0, bytemuck::bytes_of(&w));
            instance.last_weights = Some(w);
        }
    }

    /// Records the head's draws into `pass` (whose viewport the caller has set).
    pub fn paint(&self, pass: &mut wgpu::RenderPass<'_>, instance: &HeadInstance) {
        let head = &instance.head;
        pass.set_bind_group(0, &instance.bind_group, &[]);
        pass.set_vertex_buffer(0, head.vertex_buffer.slice(..));
        pass.set_index_buffer(head.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        let mut bound = None;
        let level = head.level(instance.level);
        let draws = if instance.frontal {
            &level.frontal_draws
        } else {
            &level.draws
        };
        for draw in draws {
            if let Some(material) = head.materials.get(draw.material) {
                if bound != Some(material.pipeline) {
                    bound = Some(material.pipeline);
                    pass.set_pipeline(self.pipeline(material.pipeline, instance.shading));
                }
                pass.set_bind_group(1, &material.bind_group, &[]);
                pass.draw_indexed(draw.indices.clone(), 0, 0..1);
            }
        }
    }
}
