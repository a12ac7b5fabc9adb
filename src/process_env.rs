//! Environment defaults the process sets for the libraries under it, once, in `main` before
//! any thread starts (the only time `std::env::set_var` is sound). Each returns what it set,
//! for a debug line; a value the user set is never changed.

/// Mesa's Vulkan device-select layer (`VK_LAYER_MESA_device_select`, an implicit layer loaded
/// with every Vulkan instance) connects to Wayland to find the compositor's GPU; without a
/// usable `XDG_RUNTIME_DIR` (a headless machine, a service, a container) libwayland prints
/// "error: XDG_RUNTIME_DIR is invalid or not set in the environment." twice on stderr. With no
/// runtime directory there is no compositor to ask, so the layer has nothing to decide: it is
/// turned off with its own switch, `NODEVICE_SELECT=1` (wgpu picks the adapter itself, and
/// `WGPU_ADAPTER_NAME` still names one).
pub fn quiet_vulkan_device_select() -> Option<String> {
    let runtime_dir_usable =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|dir| std::path::Path::new(&dir).is_dir());
    if runtime_dir_usable || std::env::var_os("NODEVICE_SELECT").is_some() {
        return None;
    }
    std::env::set_var("NODEVICE_SELECT", "1");
    Some(
        "no usable XDG_RUNTIME_DIR: Mesa's Vulkan device-select layer turned off \
         (NODEVICE_SELECT=1)"
            .into(),
    )
}

/// ros2-client warns at every start when `ROS_DISTRO` is unset. The node speaks the wire
/// format of the distribution ros2-client was built for (`jazzy`), so an unset `ROS_DISTRO`
/// defaults to it; a different value the user set is left for ros2-client to judge.
pub fn default_ros_distro() -> Option<String> {
    if std::env::var_os("ROS_DISTRO").is_some() {
        return None;
    }
    let distro = ros2_client::COMPILED_ROS_DISTRO.as_str();
    std::env::set_var("ROS_DISTRO", distro);
    Some(format!(
        "ROS_DISTRO is not set: taken as '{distro}', the distribution ros2-client was built for"
    ))
}

/// glibc's malloc hands every block over 128 KiB (a threshold it raises as such blocks are
/// freed) straight back to the kernel on free, and trims the heap's free top: the next frame
/// set's images, maps and scratch then fault in page by page (zeroed by the kernel) and every
/// unmap flushes the TLBs of the engine's other threads. On the paper configuration that was
/// ~1.4 ms of ~14 ms per set (`bench`, with and without `GLIBC_TUNABLES` set like this). Blocks
/// up to 32 MiB (glibc's largest threshold) come from the heap and freed memory stays with the
/// process for the next set (its peak, at most, which a live node needs again anyway). A
/// `GLIBC_TUNABLES` the user set is left alone.
pub fn keep_freed_memory() -> Option<String> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        if std::env::var_os("GLIBC_TUNABLES").is_some() {
            return None;
        }
        const MMAP_THRESHOLD: libc::c_int = 32 << 20;
        const TRIM_THRESHOLD: libc::c_int = 1 << 30;
        // SAFETY: mallopt only sets malloc's tunables; called before any thread starts.
        #[expect(unsafe_code, reason = "the one unsafe call, with its SAFETY comment")]
        let ok = unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
        };
        Some(if ok {
            "malloc keeps freed memory for the next frame set (mmap threshold 32 MiB)".into()
        } else {
            "mallopt refused the mmap/trim thresholds; malloc's defaults stay".into()
        })
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    None
}
