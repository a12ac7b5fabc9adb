// The stage registry: one table naming every WGSL stage (shader file, entry point, bindings by
// name and kind, workgroup size, override constants). build.rs `include!`s this file to combine
// each shader with common.wgsl; a test (src/sweep/gpu/shader_check.rs) checks each shader
// against its row with naga (a binding renamed or retyped, an override the engine would set but
// the shader lacks, a workgroup size changed fails `cargo test` with the stage's name); the WGSL
// engine makes its layouts, pipelines and bind groups from it by name.
// (Plain `//` comments: build.rs includes this file as items.)

/// The kind of one binding (all in group 0, numbered in table order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BindingKind {
    /// A uniform block bound whole (or at a fixed offset).
    Uniform,
    /// A uniform block bound at a dynamic offset per dispatch (a batch of planes, an SGM
    /// direction).
    DynamicUniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// One binding of a stage: the shader's variable name and its kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Binding {
    pub name: &'static str,
    pub kind: BindingKind,
}

/// One compute stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StageInfo {
    /// Also the shader file: `shaders/{name}.wgsl` (with `common.wgsl` prepended).
    pub name: &'static str,
    /// Shader files (`shaders/{prelude}.wgsl`) build.rs puts between `common.wgsl` and the
    /// stage's own: bindings and functions two stages share.
    pub prelude: &'static [&'static str],
    pub entry_point: &'static str,
    /// Binding `i` of group 0 is `bindings[i]`.
    pub bindings: &'static [Binding],
    /// The shader's `@workgroup_size`; `None` where an override constant sets it.
    pub workgroup_size: Option<[u32; 3]>,
    /// The override constants the engine sets when it specialises the stage to a plan.
    pub overrides: &'static [&'static str],
}

/// The stages, by name. `Stage::X as usize` indexes [`STAGES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    Cost,
    /// `cost_rows.wgsl`: cost and the row sums in one (per-pair aggregation over reference
    /// pairs with window sums; `SweepPlan::cost_rows`).
    CostRows,
    BoxH,
    Aggregate,
    Finalize,
    Median,
    Splat,
    Visibility,
    Sgm,
    SgmSelect,
    Census,
    Half,
    PlaneSpans,
    PlaneRanges,
    RefineBase,
    RefineSelect,
    Prefilter,
    Unpack,
}

impl Stage {
    pub const ALL: [Stage; 18] = [
        Stage::Cost,
        Stage::CostRows,
        Stage::BoxH,
        Stage::Aggregate,
        Stage::Finalize,
        Stage::Median,
        Stage::Splat,
        Stage::Visibility,
        Stage::Sgm,
        Stage::SgmSelect,
        Stage::Census,
        Stage::Half,
        Stage::PlaneSpans,
        Stage::PlaneRanges,
        Stage::RefineBase,
        Stage::RefineSelect,
        Stage::Prefilter,
        Stage::Unpack,
    ];

    /// This stage's row of the registry.
    pub fn info(self) -> &'static StageInfo {
        &STAGES[self as usize]
    }

    pub fn name(self) -> &'static str {
        self.info().name
    }
}

const fn uniform(name: &'static str) -> Binding {
    Binding {
        name,
        kind: BindingKind::Uniform,
    }
}

const fn dynamic(name: &'static str) -> Binding {
    Binding {
        name,
        kind: BindingKind::DynamicUniform,
    }
}

const fn read(name: &'static str) -> Binding {
    Binding {
        name,
        kind: BindingKind::Read,
    }
}

const fn read_write(name: &'static str) -> Binding {
    Binding {
        name,
        kind: BindingKind::ReadWrite,
    }
}

/// Columns of one reference row per workgroup of `cost_rows.wgsl` (its `ROW_LANES`).
pub const COST_ROW_LANES: u32 = 64;

/// Pixels of one row per workgroup of `sgm_select.wgsl` (its `SELECT_PIXELS`).
pub const SELECT_PIXELS: u32 = 64;

/// The 8x8 tile of reference pixels most stages run per workgroup.
const TILE: Option<[u32; 3]> = Some([8, 8, 1]);

/// The bindings of SGM's passes, shared by `sgm` and its subgroup variant (one bind group
/// serves both layouts).
const SGM_BINDINGS: &[Binding] = &[
    uniform("params"),
    dynamic("sgm_pass"),
    uniform("cameras"),
    read("images"),
    read("volume"),
    read_write("sums"),
    read_write("line_costs"),
    uniform("band"),
];

/// The registry, in `Stage` order.
pub const STAGES: [StageInfo; 18] = [
    StageInfo {
        name: "cost",
        entry_point: "main",
        prelude: &["cost_common"],
        bindings: &[
            uniform("params"),
            dynamic("batch"),
            uniform("cameras"),
            read("images"),
            read("rays"),
            read_write("cost_slab"),
            read("plane_ranges"),
            read("hypotheses"),
        ],
        workgroup_size: TILE,
        overrides: &[
            "DISTORTED",
            "SCORING",
            "PAIRS",
            "BEST_N",
            "AGGREGATION",
            "CHANNELS",
        ],
    },
    StageInfo {
        name: "cost_rows",
        entry_point: "main",
        prelude: &["cost_common"],
        bindings: &[
            uniform("params"),
            dynamic("batch"),
            uniform("cameras"),
            read("images"),
            read("rays"),
            read_write("row_sums"),
            read("plane_ranges"),
            read("hypotheses"),
        ],
        workgroup_size: Some([COST_ROW_LANES, 1, 1]),
        overrides: &["DISTORTED", "WINDOW_W", "CHANNELS"],
    },
    StageInfo {
        name: "box_h",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            dynamic("batch"),
            read("cost_slab"),
            read_write("row_sums"),
            read("plane_ranges"),
        ],
        workgroup_size: TILE,
        overrides: &["DISTORTED", "WINDOW_W", "CHANNELS"],
    },
    StageInfo {
        name: "aggregate",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            dynamic("batch"),
            read("row_sums"),
            read_write("state"),
            uniform("pairs"),
            read("cost_slab"),
            read_write("volume"),
            uniform("band"),
            read("plane_ranges"),
        ],
        workgroup_size: TILE,
        overrides: &[
            "DISTORTED",
            "WINDOW_W",
            "WINDOW_H",
            "CHANNELS",
            "AGGREGATION",
            "SCORING",
            "BEST_N",
            "WINDOW_MODE",
            "HALF_BEST_LEFT",
            "HALF_BEST_RIGHT",
            "PAIRED",
            "VOLUME",
        ],
    },
    StageInfo {
        name: "finalize",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            read("rays"),
            read("planes"),
            read("state"),
            read_write("maps"),
        ],
        workgroup_size: TILE,
        overrides: &["DISTORTED"],
    },
    StageInfo {
        name: "median",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("params"), read_write("maps")],
        workgroup_size: TILE,
        overrides: &["DISTORTED"],
    },
    StageInfo {
        name: "splat",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            uniform("cameras"),
            read("rays"),
            read("maps"),
            read_write("zbuffer"),
        ],
        workgroup_size: TILE,
        overrides: &["DISTORTED"],
    },
    StageInfo {
        name: "visibility",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            uniform("cameras"),
            read("rays"),
            read("zbuffer"),
            read_write("maps"),
        ],
        workgroup_size: TILE,
        overrides: &["DISTORTED"],
    },
    StageInfo {
        name: "sgm",
        entry_point: "main",
        prelude: &[],
        bindings: SGM_BINDINGS,
        workgroup_size: None,
        overrides: &["DISTORTED", "SGM_LANES", "LINE_PER_INVOCATION"],
    },
    StageInfo {
        name: "sgm_select",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            read("sums"),
            read_write("state"),
            uniform("band"),
            read("volume"),
        ],
        workgroup_size: Some([SELECT_PIXELS, 1, 1]),
        overrides: &["DISTORTED", "SELECT_CHUNKED"],
    },
    StageInfo {
        name: "census",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("params"), uniform("cameras"), read_write("images")],
        workgroup_size: TILE,
        overrides: &[],
    },
    // Binds the engine's image pyramid (`gpu/pyramid.rs`), not a shape's buffers.
    StageInfo {
        name: "half",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("halving"), read("finer"), read_write("coarser")],
        workgroup_size: TILE,
        overrides: &[],
    },
    // Coarse to fine on the device: the plane ranges of a level from the raw depth of the
    // level below (`coarse_depth`), in the level's command buffer before its sweep.
    StageInfo {
        name: "plane_spans",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            read("rays"),
            read("planes"),
            read("coarse_depth"),
            read_write("spans"),
        ],
        workgroup_size: Some([64, 1, 1]),
        overrides: &[],
    },
    StageInfo {
        name: "plane_ranges",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("params"), read("spans"), read_write("plane_ranges")],
        workgroup_size: TILE,
        overrides: &[],
    },
    // The fine sweep (`subpixel_refine`): its base surface before its batches (which run the
    // sweep's cost, box and aggregate stages with `Batch::refine`), its result after them.
    StageInfo {
        name: "refine_base",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            read("rays"),
            read("planes"),
            read("maps"),
            read_write("hypotheses"),
        ],
        workgroup_size: TILE,
        overrides: &[],
    },
    StageInfo {
        name: "refine_select",
        entry_point: "main",
        prelude: &[],
        bindings: &[
            uniform("params"),
            read("state"),
            read("hypotheses"),
            read_write("maps"),
        ],
        workgroup_size: TILE,
        overrides: &[],
    },
    // A pair's matching images (`prefilter.rs`) from the caller's, on the engine's image
    // pyramid (`gpu/pyramid.rs`) like `half`, before the halvings.
    StageInfo {
        name: "prefilter",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("prefilter"), read("raw"), read_write("filtered")],
        workgroup_size: TILE,
        overrides: &[],
    },
    // The caller's packed images (`image::PackedImage`) into level 0 of the engine's image
    // pyramid (or the prefilter's raw images), before the prefilter and the halvings.
    StageInfo {
        name: "unpack",
        entry_point: "main",
        prelude: &[],
        bindings: &[uniform("unpacking"), read("packed"), read_write("unpacked")],
        workgroup_size: TILE,
        overrides: &[],
    },
];

/// Variants of a stage for adapters with `wgpu::Features::SUBGROUP`: each stands in for the
/// stage it names (same bindings, so the stage's bind groups serve it), with its own shader
/// file and override constants. the shader check validates them with naga's subgroup capability; the
/// engine builds them only on a device that has the feature.
pub const SUBGROUP_VARIANTS: [(Stage, StageInfo); 1] = [(
    Stage::Sgm,
    StageInfo {
        name: "sgm_subgroup",
        entry_point: "main",
        prelude: &[],
        bindings: SGM_BINDINGS,
        workgroup_size: None,
        overrides: &["SGM_LANES", "SGM_LANE_WORDS", "SGM_LINES"],
    },
)];
