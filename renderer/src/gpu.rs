//! Headless GPU access and a small compute harness.
//!
//! [`Gpu::headless`] opens a Vulkan adapter without a window: a discrete GPU where there is
//! one, or Mesa's lavapipe (software Vulkan) on machines without. Set
//! `VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json` to force lavapipe. The
//! device gets the adapter's own limits (lavapipe's are far above wgpu's defaults).
//!
//! [`Gpu::evaluate`] runs one WGSL expression per input element in a compute shader and reads
//! the results back: it is how every WGSL radiance function is compared with its Rust twin.

use std::fmt::Write as _;

/// Why no GPU could be used; each message says what was tried.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no Vulkan adapter found ({0}); install mesa-vulkan-drivers for lavapipe")]
    NoAdapter(String),
    #[error("the adapter {adapter:?} refused a device: {message}")]
    Device { adapter: String, message: String },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("shader error in {label}: {message}")]
    Shader { label: String, message: String },
}

/// A device and queue for headless work.
pub struct Gpu {
    pub adapter_info: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

/// Says that test `test` skipped, and why, where a person sees it: on stderr (which the test
/// harness shows only for failures) and, when `TWILL_SKIP_LOG` names a file, as a line appended
/// to it; `scripts/test.sh` prints that file in a banner at the end of the run.
pub fn report_skip(test: &str, reason: &str) {
    let line = format!("SKIPPED {test}: {reason} (TWILL_ALLOW_NO_GPU=1)");
    eprintln!("{line}");
    if let Some(path) = std::env::var_os("TWILL_SKIP_LOG") {
        let appended = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .and_then(|mut f| std::io::Write::write_all(&mut f, format!("{line}\n").as_bytes()));
        if let Err(e) = appended {
            eprintln!("could not note the skip in {}: {e}", std::path::Path::new(&path).display());
        }
    }
}

impl Gpu {
    /// Opens the best Vulkan adapter available, without a window.
    pub fn headless() -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::VULKAN;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let adapter_info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("twill.device"),
            // Pass timings where the adapter can give them (lavapipe can).
            required_features: adapter.features() & wgpu::Features::TIMESTAMP_QUERY,
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device { adapter: adapter_info.name.clone(), message: e.to_string() })?;
        Ok(Self { adapter_info, device, queue })
    }

    /// The device for a GPU test named `test`: tests need an adapter and fail without one,
    /// unless `TWILL_ALLOW_NO_GPU=1` is set, in which case this prints a loud SKIPPED line and
    /// returns `None` (skipping is never silent). `scripts/test.sh` installs lavapipe, so CI
    /// always has one.
    ///
    /// # Panics
    /// When no adapter opens and `TWILL_ALLOW_NO_GPU` is not `1`.
    #[must_use]
    pub fn for_test(test: &str) -> Option<Self> {
        match Self::headless() {
            Ok(gpu) => {
                eprintln!("{test}: running on {}", gpu.describe());
                Some(gpu)
            }
            Err(e) if std::env::var("TWILL_ALLOW_NO_GPU").is_ok_and(|v| v == "1") => {
                report_skip(test, &e.to_string());
                None
            }
            Err(e) => panic!("{test}: {e}. Set TWILL_ALLOW_NO_GPU=1 to skip GPU tests explicitly."),
        }
    }

    /// A one-line description of the adapter (name, type, driver).
    #[must_use]
    pub fn describe(&self) -> String {
        let i = &self.adapter_info;
        format!("{} ({:?}, {} {})", i.name, i.device_type, i.driver, i.driver_info)
    }

    /// Evaluates `expression` (WGSL, of type `vec4<f32>`, reading the input as `input`, a
    /// `vec4<f32>`) for every element of `inputs`, after the WGSL functions in `library`.
    pub fn evaluate(
        &self,
        library: &str,
        expression: &str,
        inputs: &[[f32; 4]],
    ) -> Result<Vec<[f32; 4]>, GpuError> {
        self.evaluate_with_fabric(library, expression, inputs, None)
    }

    /// As [`Gpu::evaluate`], with a baked fabric bound as group 1 (for functions that read
    /// bake data: `library` must then include `shared/fabric_data.wgsl`, e.g.
    /// `shaders::shared_library()`).
    pub fn evaluate_with_fabric(
        &self,
        library: &str,
        expression: &str,
        inputs: &[[f32; 4]],
        fabric: Option<&crate::fabric_data::FabricData>,
    ) -> Result<Vec<[f32; 4]>, GpuError> {
        const WORKGROUP: u32 = 64;
        let mut source = String::from(library);
        let _ = write!(
            source,
            "\n@group(0) @binding(0) var<storage, read> inputs: array<vec4<f32>>;\n\
             @group(0) @binding(1) var<storage, read_write> outputs: array<vec4<f32>>;\n\
             @compute @workgroup_size({WORKGROUP})\n\
             fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
                 let i = id.x + id.y * {WORKGROUP}u * 1024u;\n\
                 if (i >= arrayLength(&inputs)) {{ return; }}\n\
                 let input = inputs[i];\n\
                 outputs[i] = {expression};\n\
             }}\n"
        );
        let device = &self.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("twill.evaluate.shader"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let io_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("twill.evaluate.bind_group_layout"),
            entries: &[0, 1].map(|binding| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: binding == 0 },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("twill.evaluate.pipeline_layout"),
            bind_group_layouts: &[Some(&io_layout), fabric.map(|f| &f.layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("twill.evaluate.pipeline"),
            layout: Some(&layout),
            module: &module,
            entry_point: Some("main"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            cache: None,
        });
        if let Some(error) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader { label: "twill.evaluate".into(), message: error.to_string() });
        }

        let count = inputs.len().max(1);
        let bytes = (count * 16) as u64;
        let input_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("twill.evaluate.inputs"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut padded = inputs.to_vec();
        padded.resize(count, [0.0; 4]);
        self.queue.write_buffer(&input_buffer, 0, bytemuck::cast_slice(&padded));
        let output_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("twill.evaluate.outputs"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("twill.evaluate.readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("twill.evaluate.bind_group"),
            layout: &io_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: input_buffer.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: output_buffer.as_entire_binding() },
            ],
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("twill.evaluate.encoder"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("twill.evaluate.pass"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            if let Some(f) = fabric {
                pass.set_bind_group(1, &f.bind_group, &[]);
            }
            let groups = (count as u32).div_ceil(WORKGROUP);
            pass.dispatch_workgroups(groups.min(1024), groups.div_ceil(1024), 1);
        }
        encoder.copy_buffer_to_buffer(&output_buffer, 0, &readback, 0, bytes);
        self.queue.submit([encoder.finish()]);

        let mut out: Vec<[f32; 4]> = read_buffer(device, &readback)?;
        out.truncate(inputs.len());
        Ok(out)
    }
}

/// Maps a `MAP_READ` buffer, waits for the device and copies its contents out.
pub fn read_buffer<T: bytemuck::Pod>(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
) -> Result<Vec<T>, GpuError> {
    let slice = buffer.slice(..);
    let (sender, receiver) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |result| {
        let _ = sender.send(result);
    });
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
    receiver
        .recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let view = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
    let out = bytemuck::cast_slice(&view).to_vec();
    drop(view);
    buffer.unmap();
    Ok(out)
}
