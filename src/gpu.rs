//! GPU setup: picks an adapter (hardware or Mesa's CPU rasterizers lavapipe/llvmpipe), opens a
//! device, turns wgpu's asynchronous errors into [`Error::Runtime`], and reads textures back.
//!
//! Adapter choice: Vulkan first, then GL; on each backend a normal request first, then a
//! fallback-adapter request, then any enumerated adapter. A CPU adapter (`DeviceType::Cpu`) is
//! accepted: that is how `bake render` runs on a machine without a GPU. The environment
//! variable `BAKE_BACKEND=vulkan|gl|auto` overrides [`BackendChoice::Auto`] (what every command
//! and test uses unless told `--backend`): the tests run once per backend that way.
//!
//! The GL backend differs from Vulkan where wgpu's GL layer fixes what Vulkan leaves to the
//! view, and the renderer asks [`Gpu`] rather than assume Vulkan's behaviour:
//! [`Gpu::array_layers`] (a texture's GL target follows its layer count at creation, so a
//! one-layer array texture is given two), and [`init_gpu`] turns on seamless cube-map filtering
//! on desktop GL (always on in Vulkan and GLES 3; wgpu leaves desktop GL's default, off).

use crate::error::{Error, Result};
use std::sync::{Arc, Mutex};

/// Which graphics API to try.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// Vulkan, then GL; or what [`BACKEND_ENV`] names ([`BackendChoice::resolve`]).
    #[default]
    Auto,
    Vulkan,
    Gl,
}

/// The environment variable that overrides [`BackendChoice::Auto`].
pub const BACKEND_ENV: &str = "BAKE_BACKEND";

impl BackendChoice {
    /// `Auto` as [`BACKEND_ENV`] sets it (`vulkan`, `gl`, or `auto`/unset/empty for Vulkan then
    /// GL); an explicit choice stays. Another value of the variable is a usage error.
    pub fn resolve(self) -> Result<BackendChoice> {
        if self != BackendChoice::Auto {
            return Ok(self);
        }
        let value = std::env::var(BACKEND_ENV).unwrap_or_default();
        match value.trim().to_ascii_lowercase().as_str() {
            "" | "auto" => Ok(BackendChoice::Auto),
            "vulkan" => Ok(BackendChoice::Vulkan),
            "gl" => Ok(BackendChoice::Gl),
            _ => Err(Error::usage(format!(
                "{BACKEND_ENV}={value:?}: expected vulkan, gl or auto"
            ))),
        }
    }

    fn order(self) -> &'static [wgpu::Backends] {
        match self {
            BackendChoice::Auto => &[wgpu::Backends::VULKAN, wgpu::Backends::GL],
            BackendChoice::Vulkan => &[wgpu::Backends::VULKAN],
            BackendChoice::Gl => &[wgpu::Backends::GL],
        }
    }
}

/// What adapter rendered, for reports.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AdapterSummary {
    pub name: String,
    /// `vulkan`, `gl`, ...
    pub backend: String,
    /// `cpu`, `integrated`, `discrete`, `virtual`, `other`.
    pub device_type: String,
    pub driver: String,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}, {}", self.name, self.backend, self.device_type)?;
        if !self.driver.is_empty() {
            write!(f, ", {}", self.driver)?;
        }
        write!(f, ")")
    }
}

/// An open device plus the errors wgpu reported asynchronously.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: AdapterSummary,
    /// The API the device runs on.
    pub backend: wgpu::Backend,
    /// Validation, out-of-memory and device-lost messages collected by callbacks.
    errors: Arc<Mutex<Vec<String>>>,
}

/// Opens a device on the first backend in `choice` (`Auto` as [`BackendChoice::resolve`] sets
/// it) that has an adapter.
pub fn init_gpu(choice: BackendChoice) -> Result<Gpu> {
    let mut tried = Vec::new();
    for &backends in choice.resolve()?.order() {
        match try_backend(backends) {
            Ok(gpu) => return Ok(gpu),
            Err(e) => tried.push(format!("{backends:?}: {e}")),
        }
    }
    Err(Error::runtime(format!(
        "no usable GPU adapter (install Mesa's lavapipe: packages mesa-vulkan-drivers \
         libvulkan1; or for GL its llvmpipe: libegl1 libegl-mesa0 libgl1-mesa-dri): {}",
        tried.join("; ")
    )))
}

/// The process' one device of the default choice ([`BackendChoice::Auto`]), opened on first
/// use and kept: for stages that use the GPU as a tool (`prt.tracer = "gpu"`), so that a scene
/// of many models opens one device. Fails, every time, with [`init_gpu`]'s message where no
/// adapter exists.
pub fn shared_gpu() -> Result<&'static Gpu> {
    static SHARED: std::sync::OnceLock<std::result::Result<Gpu, String>> =
        std::sync::OnceLock::new();
    SHARED
        .get_or_init(|| init_gpu(BackendChoice::Auto).map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|e| Error::runtime(e.clone()))
}

fn try_backend(backends: wgpu::Backends) -> std::result::Result<Gpu, String> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends,
        // No validation layers: they are rarely installed and only add noise on stderr.
        flags: wgpu::InstanceFlags::empty().with_env(),
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    let adapter = request_adapter(&instance, backends).ok_or("no adapter")?;
    let info = adapter.get_info();
    let summary = AdapterSummary {
        name: info.name.clone(),
        backend: info.backend.to_str().to_string(),
        device_type: device_type_name(info.device_type).to_string(),
        driver: [info.driver.as_str(), info.driver_info.as_str()]
            .iter()
            .filter(|s| !s.is_empty())
            .copied()
            .collect::<Vec<_>>()
            .join(" "),
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("bake render"),
        required_features: wgpu::Features::empty(),
        // Whatever the adapter offers: large terrains need its full texture size limit.
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .map_err(|e| format!("{summary}: request_device failed: {e}"))?;
    if info.backend == wgpu::Backend::Gl {
        gl_seamless_cube_maps(&device);
    }
    let errors = Arc::new(Mutex::new(Vec::new()));
    let sink = errors.clone();
    device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
        push_error(&sink, e.to_string());
    }));
    let sink = errors.clone();
    device.set_device_lost_callback(move |reason, message| {
        push_error(&sink, format!("device lost ({reason:?}): {message}"));
    });
    Ok(Gpu {
        device,
        queue,
        adapter: summary,
        backend: info.backend,
        errors,
    })
}

/// Turns on seamless cube-map filtering in a desktop GL context: GL's default samples each face
/// alone, clamped at its edges (a visible seam in the sky box, off by up to half a texel's
/// neighbour across the edge), where Vulkan and GLES 3 always filter across faces as the CPU
/// reference does (`CubeMap::sample`). wgpu never sets it and never clears it; the state belongs
/// to the device's one context.
#[cfg(any(
    windows,
    target_os = "linux",
    target_os = "android",
    target_os = "freebsd"
))]
fn gl_seamless_cube_maps(device: &wgpu::Device) {
    use glow::HasContext;
    // SAFETY: the device is a live GL device (the caller checked the backend); the context is
    // locked (and made current) for the two calls, and the flag is one wgpu-hal never touches.
    unsafe {
        if let Some(hal) = device.as_hal::<wgpu::hal::api::Gles>() {
            let gl = hal.context().lock();
            if !gl.version().is_embedded {
                gl.enable(glow::TEXTURE_CUBE_MAP_SEAMLESS);
            }
        }
    }
}

#[cfg(not(any(
    windows,
    target_os = "linux",
    target_os = "android",
    target_os = "freebsd"
)))]
fn gl_seamless_cube_maps(_device: &wgpu::Device) {}

fn request_adapter(instance: &wgpu::Instance, backends: wgpu::Backends) -> Option<wgpu::Adapter> {
    for force_fallback_adapter in [false, true] {
        let opts = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter,
            compatible_surface: None,
            ..Default::default()
        };
        if let Ok(a) = pollster::block_on(instance.request_adapter(&opts)) {
            return Some(a);
        }
    }
    pollster::block_on(instance.enumerate_adapters(backends))
        .into_iter()
        .next()
}

fn device_type_name(t: wgpu::DeviceType) -> &'static str {
    match t {
        wgpu::DeviceType::Cpu => "cpu",
        wgpu::DeviceType::IntegratedGpu => "integrated",
        wgpu::DeviceType::DiscreteGpu => "discrete",
        wgpu::DeviceType::VirtualGpu => "virtual",
        wgpu::DeviceType::Other => "other",
    }
}

fn push_error(sink: &Mutex<Vec<String>>, message: String) {
    if let Ok(mut v) = sink.lock() {
        v.push(message);
    }
}

impl Gpu {
    /// Fails with every error wgpu reported so far.
    pub fn check(&self) -> Result<()> {
        let errors = match self.errors.lock() {
            Ok(mut v) => std::mem::take(&mut *v),
            Err(_) => vec!["error log poisoned".to_string()],
        };
        if errors.is_empty() {
            Ok(())
        } else {
            Err(Error::runtime(format!(
                "GPU error on {}: {}",
                self.adapter,
                errors.join("; ")
            )))
        }
    }

    /// Blocks until the queue is idle.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| Error::runtime(format!("GPU wait failed on {}: {e}", self.adapter)))?;
        self.check()
    }

    /// The layers to give a texture of `layers` layers that is bound as a `D2Array` view:
    /// `layers`, but at least 2 on GL, where wgpu makes a one-layer texture a `TEXTURE_2D` (the
    /// target follows the layer count at creation) that an array sampler does not read (a shadow
    /// lookup then returns 0: all in shadow).
    pub fn array_layers(&self, layers: u32) -> u32 {
        match self.backend {
            wgpu::Backend::Gl => layers.max(2),
            _ => layers,
        }
    }

    /// The largest 2D texture side the device accepts.
    pub fn max_texture_side(&self) -> u32 {
        self.device.limits().max_texture_dimension_2d
    }

    /// Reads a 2D texture with 4-byte texels back into tightly packed rows.
    pub fn read_texture_rgba8(&self, texture: &wgpu::Texture) -> Result<Vec<u8>> {
        self.read_texture(texture, 4)
    }

    /// Reads a single-sample 2D texture of `texel_bytes` bytes per texel back to the CPU as
    /// tightly packed rows, row 0 first.
    pub fn read_texture(&self, texture: &wgpu::Texture, texel_bytes: u32) -> Result<Vec<u8>> {
        let (w, h) = (texture.width(), texture.height());
        let row = w * texel_bytes;
        // copy_texture_to_buffer wants rows padded to 256 bytes.
        let padded =
            row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: padded as u64 * h as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(h),
                },
            },
            texture.size(),
        );
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| Error::runtime("readback: the map callback never ran"))?
            .map_err(|e| Error::runtime(format!("readback: mapping failed: {e}")))?;
        let view = buffer
            .get_mapped_range(..)
            .map_err(|e| Error::runtime(format!("readback: {e}")))?;
        let mut out = Vec::with_capacity(row as usize * h as usize);
        for y in 0..h as usize {
            let start = y * padded as usize;
            out.extend_from_slice(&view[start..start + row as usize]);
        }
        drop(view);
        buffer.unmap();
        Ok(out)
    }
}
