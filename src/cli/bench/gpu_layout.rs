//! `bench`'s options of how the WGSL engine lays its work out on the adapter (each with the
//! adapter's choice as its default), to compare the ways on a GPU in one session.

use crate::engine::Engine;

#[derive(Debug, Clone, clap::Args)]
pub struct GpuLayout {
    /// The WGSL engine's SGM path lines per workgroup in its subgroup layout (default: the
    /// adapter's, several where its subgroups have one size; 1: a workgroup per line), to
    /// compare the two on a GPU.
    #[arg(long, value_name = "N")]
    pub sgm_lines: Option<u32>,
    /// How the WGSL engine's SGM dispatches its path directions: the adapter's (auto: all
    /// side by side on GPUs, one by one on CPU adapters), or together, first-apart (the first
    /// direction, then the others side by side) or one-by-one, to compare them on a GPU.
    #[arg(long, value_enum, default_value = "auto")]
    pub sgm_walks: crate::sweep::gpu::SgmWalks,
    /// Where the WGSL engine sums the matching costs along rows: in the stage that makes them
    /// (fused, no cost slab), in a pass of its own (apart), or the adapter's (auto: fused on
    /// GPUs), to compare the two on a GPU.
    #[arg(long, value_enum, default_value = "auto")]
    pub cost_rows: crate::sweep::gpu::CostRows,
    /// How the WGSL engine's SGM selection reads each pixel's sums and costs: through
    /// workgroup memory in chunks (chunked), each invocation its own (in-place), or the
    /// adapter's (auto: chunked on GPUs), to compare the two on a GPU.
    #[arg(long, value_enum, default_value = "auto")]
    pub select_reads: crate::sweep::gpu::SelectReads,
    /// The WGSL engine's bytes per batch of planes, MiB (default: 512 on a GPU, 192 on a CPU
    /// adapter, at most the adapter's binding limit), to compare budgets on a GPU.
    #[arg(long, value_name = "MIB")]
    pub slab_mib: Option<u64>,
    /// The WGSL engine's host copies (images in, maps out): split over threads where the set
    /// is large and the host has many cores (auto), or always on one thread / split, to
    /// compare the two on a GPU host.
    #[arg(long, value_enum, default_value = "auto")]
    pub host_copies: crate::sweep::gpu::HostCopies,
    /// The WGSL engine reads each reference of a set back before it records the next (default:
    /// every reference submitted before the first is read back), to compare the two on a GPU.
    #[arg(long)]
    pub serial_references: bool,
}

impl GpuLayout {
    /// Sets these on a WGSL engine (nothing for the CPU engine).
    pub fn apply(&self, engine: &mut Engine) {
        if let Some(lines) = self.sgm_lines {
            engine.set_sgm_lines(lines);
        }
        engine.set_sgm_walks(self.sgm_walks);
        engine.set_cost_rows(self.cost_rows);
        engine.set_select_reads(self.select_reads);
        if let Some(mib) = self.slab_mib {
            engine.set_slab_bytes(Some(mib.max(1) << 20));
        }
        engine.set_host_copies(self.host_copies);
        engine.set_submit_ahead(!self.serial_references);
    }
}
