//! Small wgpu compute helpers shared by the SVO and N-tree kernels ([`super::gpu`],
//! [`crate::linespace::gpu`]): a pipeline with one bind group (binding 0 a uniform, then
//! read-only storage buffers, then one read-write output), buffer upload and read-back, and a 2D
//! dispatch grid for batches larger than 65,535 workgroups.

use crate::error::{Error, Result};
use crate::gpu::Gpu;
use wgpu::util::DeviceExt;

/// Invocations per workgroup (`@workgroup_size(64)` in the shaders).
pub const WORKGROUP: u32 = 64;

/// A compute pipeline over bindings `0` (uniform), `1..=inputs` (read-only storage) and
/// `inputs + 1` (read-write storage).
pub struct Kernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    inputs: u32,
}

fn buffer_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl Kernel {
    /// Compiles `source` (the concatenated WGSL parts) and fails with wgpu's message if it does
    /// not validate.
    pub fn new(gpu: &Gpu, label: &str, parts: &[&str], entry: &str, inputs: u32) -> Result<Self> {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(parts.concat().into()),
        });
        let mut entries = vec![buffer_entry(0, wgpu::BufferBindingType::Uniform)];
        for b in 1..=inputs {
            entries.push(buffer_entry(
                b,
                wgpu::BufferBindingType::Storage { read_only: true },
            ));
        }
        entries.push(buffer_entry(
            inputs + 1,
            wgpu::BufferBindingType::Storage { read_only: false },
        ));
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &entries,
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: Some(&pl),
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        gpu.check()?;
        Ok(Kernel {
            pipeline,
            layout,
            inputs,
        })
    }

    /// Records one dispatch of `grid` workgroups into `enc`.
    pub fn record(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        uniform: &wgpu::Buffer,
        inputs: &[&wgpu::Buffer],
        output: &wgpu::Buffer,
        grid: [u32; 2],
    ) -> Result<()> {
        if inputs.len() != self.inputs as usize {
            return Err(Error::runtime("kernel: wrong number of input buffers"));
        }
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }];
        for (i, b) in inputs.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry {
                binding: 1 + i as u32,
                resource: b.as_entire_binding(),
            });
        }
        entries.push(wgpu::BindGroupEntry {
            binding: 1 + self.inputs,
            resource: output.as_entire_binding(),
        });
        let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &entries,
        });
        if grid[0] * grid[1] == 0 {
            return Ok(());
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: None,
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(grid[0], grid[1], 1);
        Ok(())
    }

    /// Runs one dispatch and reads `output` back (its first `bytes` bytes).
    pub fn run(
        &self,
        gpu: &Gpu,
        uniform: &wgpu::Buffer,
        inputs: &[&wgpu::Buffer],
        output: &wgpu::Buffer,
        grid: [u32; 2],
        bytes: u64,
    ) -> Result<Vec<u8>> {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.record(gpu, &mut enc, uniform, inputs, output, grid)?;
        gpu.queue.submit([enc.finish()]);
        read_back(gpu, output, bytes)
    }
}

/// Workgroups (x, y) and the invocation stride of row y for `count` invocations.
pub fn grid_for(count: u32) -> ([u32; 2], u32) {
    let groups = count.div_ceil(WORKGROUP);
    let x = groups.clamp(1, 65_535);
    let y = groups.div_ceil(x);
    ([x, y], x * WORKGROUP)
}

/// A storage buffer holding `bytes` (padded to a multiple of 4 and at least 16 bytes: wgpu
/// rejects empty bindings).
pub fn storage(gpu: &Gpu, label: &str, bytes: &[u8]) -> Result<wgpu::Buffer> {
    let limit = gpu.device.limits().max_storage_buffer_binding_size;
    if bytes.len() as u64 > limit {
        return Err(Error::runtime(format!(
            "{label}: {} bytes exceed the device's storage-buffer limit of {limit} bytes",
            bytes.len()
        )));
    }
    let padded = bytes.len().next_multiple_of(4).max(16);
    let mut data = bytes.to_vec();
    data.resize(padded, 0);
    Ok(gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: &data,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        }))
}

/// A uniform buffer from `bytes`.
pub fn uniform(gpu: &Gpu, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: wgpu::BufferUsages::UNIFORM,
        })
}

/// A read-write storage buffer of `bytes` (at least 16) that can be copied out.
pub fn output(gpu: &Gpu, label: &str, bytes: u64) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.next_multiple_of(4).max(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Copies the first `bytes` bytes of `src` to the CPU.
pub fn read_back(gpu: &Gpu, src: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>> {
    let size = bytes.next_multiple_of(4).max(4);
    let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("compute readback"),
        size,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(src, 0, &staging, 0, size);
    gpu.queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
    rx.recv()
        .map_err(|_| Error::runtime("readback: the map callback never ran"))?
        .map_err(|e| Error::runtime(format!("readback: mapping failed: {e}")))?;
    let view = staging
        .get_mapped_range(..)
        .map_err(|e| Error::runtime(format!("readback: {e}")))?;
    let out = view[..bytes as usize].to_vec();
    drop(view);
    staging.unmap();
    Ok(out)
}
