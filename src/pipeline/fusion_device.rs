//! Where live fusion integrates (`fusion_device`): on a GPU through `fusion::GpuTsdf`, or on
//! the CPU. [`fusion_gpu`] decides, for the depth node and `bag` beside their engine, for the
//! `fuse` node alone, and says why.
//!
//! `auto` fuses on a GPU only when it is a hardware adapter: on a CPU adapter (Mesa's lavapipe,
//! wgpu's answer on a machine without a GPU) the device's integration runs as CPU code behind
//! the Vulkan emulation and takes several times the CPU integrator's time on the same cores
//! (`bench --fusion --device gpu`, docs/fusion.md), while taking those cores from the engine.

use crate::engine::Device;
use crate::gpu_context::{GpuContext, GpuContextError};

/// What fusion runs beside.
#[derive(Clone, Copy)]
pub enum FusionHost<'a> {
    /// The depth node's or `bag`'s engine: the WGSL engine's device (None: the CPU engine).
    Engine(Option<&'a GpuContext>),
    /// Nothing: the `fuse` node, which opens its own device when it fuses on a GPU.
    Alone,
}

/// Where fusion integrates, and why (for the start-up log).
pub struct FusionPlacement {
    /// The device (None: the CPU).
    pub gpu: Option<GpuContext>,
    /// On the engine's own device: when the engine makes its device anew after a loss, the map
    /// follows ([`super::FuserThread::follow_device`]).
    pub engine_device: bool,
    pub why: String,
}

impl FusionPlacement {
    fn cpu(why: impl Into<String>) -> Self {
        Self {
            gpu: None,
            engine_device: false,
            why: why.into(),
        }
    }

    fn gpu(gpu: GpuContext, why: &str) -> Self {
        let why = format!("{why}: {}", gpu.adapter_label());
        Self {
            gpu: Some(gpu),
            engine_device: false,
            why,
        }
    }

    /// On the engine's device.
    fn engine(gpu: &GpuContext, why: &str) -> Self {
        Self {
            engine_device: true,
            ..Self::gpu(gpu.clone(), why)
        }
    }

    /// "on the GPU (why)" or "on the CPU (why)".
    pub fn label(&self) -> String {
        let on = if self.gpu.is_some() { "GPU" } else { "CPU" };
        format!("on the {on} ({})", self.why)
    }
}

/// Whether `auto` fuses on an adapter of this type: not on a CPU adapter (lavapipe).
pub fn auto_fuses_on(device_type: wgpu::DeviceType) -> bool {
    device_type != wgpu::DeviceType::Cpu
}

/// Where fusion integrates for `fusion_device` `choice` beside `host`: `cpu` on the CPU; `gpu`
/// on the engine's device, else on one opened for it (any adapter, lavapipe too; no adapter is
/// an error); `auto` on the engine's device when it is a hardware GPU, alone on a hardware GPU
/// if wgpu offers one ([`crate::engine::hardware_gpu`]), else on the CPU (never an error).
pub fn fusion_gpu(
    choice: Device,
    host: FusionHost<'_>,
) -> Result<FusionPlacement, GpuContextError> {
    Ok(match (choice, host) {
        (Device::Cpu, _) => FusionPlacement::cpu("fusion_device cpu"),
        (Device::Gpu, FusionHost::Engine(Some(gpu))) => {
            FusionPlacement::engine(gpu, "fusion_device gpu, the engine's device")
        }
        (Device::Gpu, _) => FusionPlacement::gpu(GpuContext::new()?, "fusion_device gpu"),
        (Device::Auto, FusionHost::Engine(None)) => {
            FusionPlacement::cpu("fusion_device auto beside the CPU engine")
        }
        (Device::Auto, FusionHost::Engine(Some(gpu))) => {
            let info = gpu.adapter.get_info();
            if auto_fuses_on(info.device_type) {
                FusionPlacement::engine(gpu, "fusion_device auto, the engine's GPU")
            } else {
                FusionPlacement::cpu(format!(
                    "fusion_device auto: the engine's adapter '{}' is a CPU adapter, where the \
                     CPU integrator is faster",
                    info.name
                ))
            }
        }
        (Device::Auto, FusionHost::Alone) => match crate::engine::hardware_gpu() {
            Some(gpu) => FusionPlacement::gpu(gpu, "fusion_device auto, a hardware GPU"),
            None => FusionPlacement::cpu("fusion_device auto: no hardware GPU"),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On lavapipe (a CPU adapter, as CI and the 2-core machine have) `auto` fuses on the CPU
    /// (on a hardware GPU, on the engine's device) and `gpu` on the engine's own device; `cpu` and a CPU engine never touch a GPU.
    #[test]
    fn auto_leaves_a_cpu_adapter_and_gpu_takes_the_engines_device() {
        assert!(auto_fuses_on(wgpu::DeviceType::DiscreteGpu));
        assert!(auto_fuses_on(wgpu::DeviceType::IntegratedGpu));
        assert!(!auto_fuses_on(wgpu::DeviceType::Cpu));
        let (gpu, _one_at_a_time) = crate::fusion::gpu::tests::gpu();
        let engine = FusionHost::Engine(Some(gpu));
        let auto = fusion_gpu(Device::Auto, engine).expect("auto never fails");
        if gpu.adapter.get_info().device_type == wgpu::DeviceType::Cpu {
            assert!(auto.gpu.is_none(), "{}", auto.label());
            assert!(auto.label().contains("CPU adapter"), "{}", auto.label());
        } else {
            // A hardware GPU (a lent machine): the engine's device.
            let device = auto.gpu.as_ref().expect("on the engine's GPU");
            assert!(device.device == gpu.device, "{}", auto.label());
        }
        let on = fusion_gpu(Device::Gpu, engine).expect("the engine's device");
        let device = on.gpu.as_ref().expect("on the GPU");
        assert!(device.device == gpu.device, "the engine's own device");
        assert!(on.label().starts_with("on the GPU"), "{}", on.label());
        for (choice, host) in [
            (Device::Cpu, engine),
            (Device::Cpu, FusionHost::Alone),
            (Device::Auto, FusionHost::Engine(None)),
        ] {
            let placed = fusion_gpu(choice, host).expect("the CPU");
            assert!(placed.gpu.is_none(), "{}", placed.label());
        }
    }
}
