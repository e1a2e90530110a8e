//! The vertex shader's blend run in a compute pass and read back, so tests can compare the
//! GPU's blend with the CPU reference.

use super::frame::HeadInstance;
use super::pipelines::HeadRenderer;
use crate::render::RenderError;
use crate::render::head::MorphDelta;

impl HeadRenderer {
    /// Runs the vertex shader's blend function in a compute pass and reads back the blended
    /// positions and normals (all slots, in head space: before the model matrix), in the model's
    /// primitive/vertex order (for tests and debugging). Uses the weights and pose last written
    /// by [`Self::prepare`]; [`HeadModel::blend_cpu_posed`] is its CPU reference.
    ///
    /// [`HeadModel::blend_cpu_posed`]: crate::render::HeadModel::blend_cpu_posed
    pub fn blend_on_gpu(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        instance: &HeadInstance,
    ) -> Result<Vec<MorphDelta>, RenderError> {
        let head = &instance.head;
        let blend_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("lipcall blend readback layout"),
            entries: &[storage_entry(0, true), storage_entry(1, false)],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("lipcall blend readback pipeline layout"),
            bind_group_layouts: &[Some(&self.head_layout), None, Some(&blend_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("lipcall blend readback pipeline"),
            layout: Some(&layout),
            module: &self.shader,
            entry_point: Some("cs_blend"),
            compilation_options: Default::default(),
            cache: None,
        });
        let out_size = (head.vertex_count as u64 * std::mem::size_of::<MorphDelta>() as u64).max(4);
        let out = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall blend readback output"),
            size: out_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lipcall blend readback staging"),
            size: out_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("lipcall blend readback bind group"),
            layout: &blend_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: head.vertex_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: out.as_entire_binding(),
                },
            ],
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("lipcall blend readback encoder"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("lipcall blend readback pass"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &instance.bind_group, &[]);
            pass.set_bind_group(2, &bind_group, &[]);
            pass.dispatch_workgroups(head.vertex_count.div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&out, 0, &staging, 0, out_size);
        queue.submit([encoder.finish()]);
        let bytes = crate::render::readback::read_buffer(device, &staging)?;
        let used = head.vertex_count as usize * std::mem::size_of::<MorphDelta>();
        let gpu: Vec<MorphDelta> = bytemuck::pod_collect_to_vec(
            bytes
                .get(..used)
                .ok_or_else(|| RenderError::Readback("short blend readback".into()))?,
        );
        Ok(head.model_to_gpu.iter().map(|&g| gpu[g as usize]).collect())
    }
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}
