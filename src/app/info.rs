//! `vkshade info`: the Vulkan devices present, the limits that matter to the kernels, and
//! whether the validation layer is installed.

use crate::error::Result;
use crate::gpu::DeviceInfo;
use std::path::PathBuf;

/// The arguments of `vkshade info`.
#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Also write the report as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

impl Args {
    /// Prints every device (and writes the JSON report when asked).
    pub fn run(&self) -> Result<()> {
        let sys = crate::gpu::enumerate_devices()?;
        println!("Vulkan loader {}", sys.loader_version);
        println!(
            "validation layer VK_LAYER_KHRONOS_validation: {}",
            if sys.validation_layer {
                "installed"
            } else {
                "NOT installed (apt-get install vulkan-validationlayers)"
            }
        );
        if sys.devices.is_empty() {
            println!("no Vulkan devices found; {}", crate::error::INSTALL_HINT);
        }
        for d in &sys.devices {
            print_device(d);
        }
        if let Some(path) = &self.json {
            crate::io::write_json(path, &sys)?;
            println!("\nwrote {}", path.display());
        }
        Ok(())
    }
}

/// One device: name, type, versions, whether vkshade can use it, and its limits.
fn print_device(d: &DeviceInfo) {
    let l = &d.limits;
    println!(
        "\n[{}] {} ({}), Vulkan {}, driver {}",
        d.index, d.name, d.device_type, d.api_version, d.driver
    );
    match &d.usable {
        Ok(()) => println!("    usable by vkshade: yes"),
        Err(why) => println!("    usable by vkshade: NO ({why})"),
    }
    let mib = |b: u64| format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64);
    println!(
        "    device-local memory         {}",
        mib(d.device_local_bytes)
    );
    println!(
        "    maxStorageBufferRange       {}",
        mib(l.max_storage_buffer_range)
    );
    println!(
        "    maxMemoryAllocationSize     {}",
        mib(l.max_memory_allocation_size)
    );
    println!(
        "    maxUniformBufferRange       {} B",
        l.max_uniform_buffer_range
    );
    println!(
        "    maxPushConstantsSize        {} B",
        l.max_push_constants_size
    );
    println!(
        "    maxImageDimension2D / 3D    {} / {}",
        l.max_image_dimension_2d, l.max_image_dimension_3d
    );
    println!(
        "    maxImageArrayLayers         {}",
        l.max_image_array_layers
    );
    println!(
        "    maxComputeSharedMemorySize  {} B",
        l.max_compute_shared_memory_size
    );
    println!(
        "    maxComputeWorkGroupInvocations {}",
        l.max_compute_work_group_invocations
    );
    println!(
        "    maxComputeWorkGroupSize     {:?}",
        l.max_compute_work_group_size
    );
    println!(
        "    maxComputeWorkGroupCount    {:?}",
        l.max_compute_work_group_count
    );
    println!("    subgroupSize                {}", l.subgroup_size);
    println!(
        "    timestamps                  {} valid bits, {} ns/tick",
        l.timestamp_valid_bits, l.timestamp_period_ns
    );
}
