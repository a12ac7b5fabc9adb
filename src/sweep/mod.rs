//! The multi-view plane sweep (Woetzel & Koch 2004): parameters, inputs, outputs, and the two
//! engines that run it, [`gpu::GpuEngine`] (wgpu compute shaders in `shaders/`) and its stage-by-stage
//! CPU twin [`cpu::CpuEngine`].

pub mod census;
pub mod coarse;
pub mod cpu;
pub mod frame_memo;
pub mod gpu;
pub mod gpu_types;
pub mod hypotheses;
pub mod joint_median;
pub mod plan;
pub mod prefilter;
pub mod rectify;
pub mod references;
pub mod schedule;
pub mod stages;

use serde::{Deserialize, Serialize};

use crate::geometry::{GeometryError, Rig};
use crate::image::{ImageF32, SetImages};

pub use hypotheses::{HypothesisGenerator, InverseDepthSweep, Plane, PlaneFamily};

/// How the camera pairs of one hypothesis are combined into one score.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Scoring {
    /// Mean TSSD over the pairs (reference pairs: Yang's SSSD).
    Sssd,
    /// Mean TSSD over all pairs among the visible cameras.
    AllPairs,
    /// Mean of the `best_n` smallest pair TSSDs.
    BestNOfM,
    /// min(left half's score, right half's score), each half the mean of its best pairs
    /// (`half_best_n`, `SweepPlan::half_ranks`); the default. A virtual reference with no
    /// pair on one side (pairs straddling it in neither half) scores best n of m instead.
    BestHalfSequence,
}

/// What the colour term of the cost compares (issue 52, `prefilter.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Prefilter {
    /// `gradient` for a pair of cameras (a stereo camera: no third view to outvote a pair
    /// that radiometry breaks); for more, `gradient` from the first frame set whose images
    /// are a camera's ([`prefilter::AUTO_RENDER_STEP`]) or whose cameras' mean brightness
    /// differs by more than [`prefilter::AUTO_BRIGHTNESS_RATIO`], else `none` (renders of
    /// high-contrast texture; `coarse::Plans`).
    Auto,
    /// The camera images as they are (lab sets: equal exposures, clean images).
    None,
    /// Each image's horizontal derivative (OpenCV StereoSGBM's prefilter): blind to offsets,
    /// exposure and vignetting between cameras; census and SGM's edges still see the raw grey.
    Gradient,
}

impl Prefilter {
    /// Whether a rig of `cameras` cameras sweeps prefiltered images (`Auto` as it stands before
    /// a frame set is seen: a pair only).
    pub fn applies(self, cameras: usize) -> bool {
        match self {
            Prefilter::Auto => cameras == 2,
            Prefilter::None => false,
            Prefilter::Gradient => true,
        }
    }
}

/// The matching cost of one camera pair at one hypothesis (`tau` sets the scale of all three).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Cost {
    /// Truncated squared RGB difference of the bilinear samples: min(tau, |a - b|^2).
    Tssd,
    /// Hamming distance of the 5 x 5 census words (`sweep/census.rs`), tau / 24 per bit:
    /// blind to gain and offset between cameras.
    Census,
    /// The mean of the two (Mei et al.'s AD-census in spirit).
    AdCensus,
}

/// Which camera pairs are scored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum PairSet {
    /// Reference vs every other camera (m = N - 1).
    Reference,
    /// All pairs among the visible cameras (m = N (N - 1) / 2).
    All,
}

/// Where the shiftable windows aggregate (ALGORITHM.md stage 4, "ours").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Aggregation {
    /// Windows average the scored cost (the paper's pipeline).
    Scored,
    /// Best half-sequence only: windows average each half's cost, then the min is taken.
    PerHalf,
    /// Windows average each camera pair's TSSD; the score (best n, half-sequence, ...) is taken
    /// over the window means, so one window picks one consistent set of pairs.
    PerPair,
}

/// Where the aggregation windows sit relative to the pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum WindowMode {
    /// The four w x h windows with the pixel at a corner; the best one wins (the paper's
    /// shiftable windows; w and h must be 1 or even).
    Shiftable,
    /// One w x h window around the pixel (odd sizes are symmetric).
    Centred,
}

/// How the depth is chosen from the scored costs of each pixel (ALGORITHM.md stage 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Optimizer {
    /// Local winner-take-all over each pixel's hypotheses (the paper); streams over plane
    /// batches, no cost volume.
    Wta,
    /// Semi-global matching: the scored costs go into a compact (u16) cost volume, path-wise
    /// dynamic programming along `sgm_paths` directions with penalties P1 / P2 is summed, then
    /// winner-take-all on the sum (`shaders/sgm.wgsl`, `shaders/sgm_select.wgsl`).
    Sgm,
}

/// The views (cameras besides itself) a reference sweeps with when `max_neighbours` is 0: more
/// cameras than this are chosen among (`geometry::neighbours`). On a dense 21-frame
/// trajectory the 8 best views beat every fifth frame and all frames (docs/engine.md).
pub const AUTO_NEIGHBOURS: usize = 8;

/// The most planes a sweep takes (`num_planes`; SGM's own limit is
/// [`gpu_types::MAX_SGM_PLANES`]).
pub const MAX_PLANES: u32 = 4096;

/// Engine parameters. Their defaults (measured best on the shared data, see docs/quality.md), node
/// parameter names, command-line options, ranges and descriptions are declared once, in
/// `src/params/engine.rs`, which also implements `Default` for this struct.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SweepParams {
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    pub num_planes: u32,
    pub cost: Cost,
    pub scoring: Scoring,
    pub pairs: PairSet,
    /// n of best n of m.
    pub best_n: u32,
    /// Best half-sequence with per-pair aggregation scores each half by the mean of its n best
    /// pairs, n at most half the half's pairs rounded up (0 = all pairs of the half, the
    /// paper's rule; at most 4).
    pub half_best_n: u32,
    pub aggregation: Aggregation,
    /// Window width and height in pixels: 1x1 = no aggregation, 2x2 = the paper's shiftable
    /// window, 2n x 2m = larger shiftable windows.
    pub window_width: u32,
    pub window_height: u32,
    pub window_mode: WindowMode,
    /// Truncation of the colour SSD (sum over RGB of squared 0..255 differences).
    pub tau: f32,
    /// A best score above this is invalid.
    pub max_cost: f32,
    /// Keep the depth of a pixel whose best plane is the first or the last of the range
    /// (false: such a pixel is invalid, its surface likely outside the range). The levels below
    /// a coarse-to-fine sweep keep them: their depths only narrow the next level's planes.
    pub keep_range_ends: bool,
    pub subpixel: bool,
    /// With `subpixel`: the V (equiangular line) through the three scores instead of the
    /// parabola (`cpu::finalize::subpixel_offset`; issue 29, docs/quality.md).
    pub subpixel_v_fit: bool,
    /// With `subpixel`: the fine local sweep around the parabola's depth (`cpu/refine.rs`, its
    /// WGSL twin the `refine_base` and `refine_select` stages around refine batches of the
    /// sweep's stages).
    pub subpixel_refine: bool,
    pub median: bool,
    /// The CPU engine sweeps a pair of cameras whose images are not rectified as a rectified
    /// pair (`rectify.rs`).
    pub rectify_pairs: bool,
    /// Radius of the colour-weighted median after the sweep (`joint_median.rs`); 0 = off.
    pub joint_median_radius: u32,
    /// Its colour scale: the L1 RGB difference at which a neighbour's weight is 1/e.
    pub joint_median_colour: f32,
    /// Whether it fills invalid pixels (from neighbours of their own colour).
    pub joint_median_fill: bool,
    /// Pixels seen by fewer cameras (the reference counted) are invalid; 0 or 1 disables.
    pub min_visible_cameras: u32,
    /// Relative depth tolerance of the occlusion z-test.
    pub occlusion_tolerance: f32,
    /// A half is "clearly better" when its score is below (1 - margin) times the other's.
    pub half_margin: f32,
    pub optimizer: Optimizer,
    /// SGM penalty for a change of one plane between neighbours, in score units (those of
    /// `tau`).
    pub sgm_p1: f32,
    /// SGM penalty for a change of more than one plane, in score units.
    pub sgm_p2: f32,
    /// SGM path directions: 4 (horizontal and vertical) or 8 (plus diagonals).
    pub sgm_paths: u32,
    /// Colour step (largest RGB channel difference between path neighbours, 0..255) at which
    /// P2 is halved: P2 / (1 + step / sgm_edge), at least P1; 0 keeps P2 constant.
    pub sgm_edge: f32,
    /// Sweep at half resolution first, then each full-resolution row only over the planes
    /// its neighbourhood needs (`sweep/coarse.rs`).
    pub coarse_to_fine: bool,
    /// Cameras each reference sweeps with besides itself, at most (0: [`AUTO_NEIGHBOURS`]),
    /// chosen by `geometry::neighbours`. Applies where references choose their cameras
    /// (`Sweeper::run_references` and `run_views`: the node, `bag`, `eval`, `bench`); `run`
    /// sweeps the rig it is given.
    pub max_neighbours: u32,
    /// What the colour term of the cost compares (`prefilter.rs`).
    pub prefilter: Prefilter,
    /// Pixels whose winner is not unique on the matching costs by this share are invalid
    /// (`finalize`; 0 = none). With SGM: SGM's winner against the best plane more than
    /// [`gpu_types::UNIQUENESS_RADIUS_PX`] of shift away, `(rival - best) / (rival + 1)` on the
    /// matching costs; with winner-take-all: its own confidence.
    pub uniqueness: f32,
    /// With SGM: the confidence of a pixel whose winner is unique on the matching costs by less
    /// than this share (as `uniqueness` measures it) is scaled by `share / ambiguity`, so that a
    /// repeated pattern's or a blank surface's depth is not confident; 0 = SGM's own.
    pub ambiguity: f32,
}

/// Errors from the engines.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("invalid parameter: {0}")]
    InvalidParams(String),
    #[error(
        "camera '{camera}': image is {got_w}x{got_h} but its camera model says {want_w}x{want_h}"
    )]
    ImageSize {
        camera: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
    #[error("got {images} images for a rig of {cameras} cameras")]
    ImageCount { images: usize, cameras: usize },
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error("GPU: {0}")]
    Gpu(String),
    /// The run was stopped between passes by its [`CancelFlag`] (the node shutting down).
    #[error("the run was cancelled")]
    Cancelled,
    /// A reference camera that no other camera of the rig sees (`references`).
    #[error("reference camera '{reference}': no other camera sees at least 10 % of its view between {min_depth_m} and {max_depth_m} m from far enough to give a pixel of parallax, so it has no pair to match (point another camera at what it sees, check the rig's translations, in metres, or leave it out of references)")]
    NoNeighbours {
        reference: String,
        min_depth_m: f64,
        max_depth_m: f64,
    },
    /// A reference index outside the frame set's cameras.
    #[error("reference {index} is not a camera of the set ({cameras} cameras)")]
    NoSuchReference { index: usize, cameras: usize },
}

/// Asks a running engine to stop at its next pass boundary (the CPU engine: between planes
/// and between stages; the WGSL engine: between submissions and while it waits for the GPU),
/// so that a node shutting down does not finish a set nobody will receive. Clones share the
/// flag; once cancelled it stays cancelled.
#[derive(Debug, Clone, Default)]
pub struct CancelFlag(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl CancelFlag {
    pub fn new() -> Self {
        Self::default()
    }

    /// Every engine holding a clone stops at its next pass boundary with
    /// [`SweepError::Cancelled`].
    pub fn cancel(&self) {
        self.0.store(true, std::sync::atomic::Ordering::SeqCst);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// `Err(Cancelled)` once cancelled.
    pub fn check(&self) -> Result<(), SweepError> {
        if self.is_cancelled() {
            Err(SweepError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// What [`SweepParams::validate`] needs of a rig: how many cameras it has and whether its
/// reference is one of them (a virtual reference has no image). The node checks its parameters
/// against this before any camera is calibrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RigShape {
    pub cameras: usize,
    pub real_reference: bool,
    /// Each real reference sweeps with its [`SweepParams::neighbour_count`] best views
    /// (`references::reference_rig`: the node and `bag`), not with the whole rig.
    pub views_chosen: bool,
}

impl RigShape {
    /// The shape of `rig` swept whole.
    pub fn of(rig: &Rig) -> Self {
        Self {
            cameras: rig.cameras.len(),
            real_reference: rig.reference_index().is_some(),
            views_chosen: false,
        }
    }

    /// The node's and `bag`'s rig of `cameras`: a real reference sweeps with its best views,
    /// a virtual one with every camera.
    pub fn chosen_views(cameras: usize, real_reference: bool) -> Self {
        Self {
            cameras,
            real_reference,
            views_chosen: real_reference,
        }
    }

    /// How many cameras one sweep takes under `params`: the reference and its chosen views,
    /// or the whole rig.
    pub fn swept(&self, params: &SweepParams) -> usize {
        if self.views_chosen && self.real_reference {
            self.cameras.min(1 + params.neighbour_count())
        } else {
            self.cameras
        }
    }
}

impl SweepParams {
    /// Checks ranges and the combination with the rig; every engine calls this first.
    pub fn validate(&self, rig: &Rig) -> Result<(), SweepError> {
        self.validate_shape(RigShape::of(rig))
    }

    /// `min_depth` and `max_depth` make a range: finite, above 0, the first below the second
    /// (`!(a && b)` tests: NaN fails them).
    pub fn check_depth_range(&self) -> Result<(), SweepError> {
        let bad = |m: String| Err(SweepError::InvalidParams(m));
        if !(self.min_depth_m > 0.0 && self.min_depth_m.is_finite()) {
            return bad(format!(
                "min_depth must be a finite number of metres > 0, got {}",
                self.min_depth_m
            ));
        }
        if !(self.max_depth_m > self.min_depth_m && self.max_depth_m.is_finite()) {
            return bad(format!(
                "max_depth ({} m) must be finite and greater than min_depth ({} m)",
                crate::geometry::metres(self.max_depth_m),
                crate::geometry::metres(self.min_depth_m)
            ));
        }
        Ok(())
    }

    /// [`SweepParams::validate`] against a rig's shape.
    // `!(x > 0.0)` on purpose: it also rejects NaN.
    #[expect(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
    )]
    pub fn validate_shape(&self, shape: RigShape) -> Result<(), SweepError> {
        let bad = |m: String| Err(SweepError::InvalidParams(m));
        self.check_depth_range()?;
        if self.num_planes < 2 || self.num_planes > MAX_PLANES {
            return bad(format!(
                "num_planes must be in 2..={MAX_PLANES}, got {}",
                self.num_planes
            ));
        }
        for (name, v) in [
            ("window_width", self.window_width),
            ("window_height", self.window_height),
        ] {
            if v == 0 || v > 33 {
                return bad(format!("{name} must be in 1..=33, got {v}"));
            }
            if self.window_mode == WindowMode::Shiftable && v != 1 && v % 2 != 0 {
                return bad(format!(
                    "{name} of a shiftable window must be 1 or even (2n), got {v}"
                ));
            }
        }
        if !(self.tau > 0.0) {
            return bad(format!("tau must be > 0, got {}", self.tau));
        }
        if !(self.max_cost > 0.0) {
            return bad(format!("max_cost must be > 0, got {}", self.max_cost));
        }
        if !(self.occlusion_tolerance >= 0.0) {
            return bad("occlusion_tolerance must be >= 0".into());
        }
        if !(0.0..1.0).contains(&self.half_margin) {
            return bad("half_margin must be in [0, 1)".into());
        }
        if self.scoring == Scoring::BestNOfM
            && (self.best_n == 0 || self.best_n > gpu_types::MAX_BEST_N)
        {
            return bad(format!(
                "best_n must be in 1..={}, got {}",
                gpu_types::MAX_BEST_N,
                self.best_n
            ));
        }
        if self.half_best_n > gpu_types::MAX_HALF_BEST_N {
            return bad(format!(
                "half_best_n must be in 0..={} (0 = all pairs of a half), got {}",
                gpu_types::MAX_HALF_BEST_N,
                self.half_best_n
            ));
        }
        if self.subpixel_refine && !self.subpixel {
            return bad(
                "subpixel_refine refines the sub-pixel depth: it needs subpixel true".into(),
            );
        }
        if self.subpixel_refine && self.cost != Cost::Tssd && self.effective_pairs() == PairSet::All
        {
            return bad(format!(
                "subpixel_refine costs each pixel at its own depth, which the census cost between two sampled cameras (pairs all{}) cannot: use pairs reference or cost tssd",
                if self.scoring == Scoring::AllPairs {
                    ", which scoring all_pairs implies"
                } else {
                    ""
                }
            ));
        }
        self.validate_sgm()?;
        let pairs = self.effective_pairs();
        if pairs == PairSet::Reference && !shape.real_reference {
            return bad(format!(
                "scoring '{:?}' with reference pairs needs a real reference camera; a virtual reference has no image (use pairs = all)",
                self.scoring
            ));
        }
        if shape.cameras > gpu_types::MAX_RIG_CAMERAS as usize {
            return bad(format!(
                "the engine supports at most {} cameras per rig, got {}",
                gpu_types::MAX_RIG_CAMERAS,
                shape.cameras
            ));
        }
        // The parameters' own names for the message (`aggregation: per_pair`, `pairs: all`).
        let names = format!(
            "aggregation {} with pairs {}",
            match self.aggregation {
                Aggregation::Scored => "scored",
                Aggregation::PerHalf => "per_half",
                Aggregation::PerPair => "per_pair",
            },
            match pairs {
                PairSet::Reference => "reference",
                PairSet::All => "all",
            }
        );
        if self.max_neighbours as usize > self.max_views() {
            return bad(format!(
                "max_neighbours {} is more views than one reference can sweep with under {names}: at most {} (0 takes the {} best)",
                self.max_neighbours,
                self.max_views(),
                AUTO_NEIGHBOURS.min(self.max_views())
            ));
        }
        if self.aggregation == Aggregation::PerPair {
            let n = shape.swept(self);
            let m = match pairs {
                PairSet::Reference => n - 1,
                PairSet::All => n * (n - 1) / 2,
            };
            if m > gpu_types::MAX_PAIRS as usize {
                let fix = if shape.views_chosen && shape.real_reference {
                    format!("max_neighbours <= {}", self.max_views())
                } else {
                    format!(
                        "let each reference choose its views (`Sweeper::run_views` or `run_references` with max_neighbours <= {})",
                        self.max_views()
                    )
                };
                return bad(format!(
                    "{names} holds at most {} camera pairs; {n} cameras swept together make {m} (set {fix}, or aggregation scored)",
                    gpu_types::MAX_PAIRS,
                ));
            }
        }
        if pairs == PairSet::All && shape.swept(self) > gpu_types::MAX_CAMERAS as usize {
            return bad(format!(
                "all-pairs scoring supports at most {} cameras, the rig has {}",
                gpu_types::MAX_CAMERAS,
                shape.swept(self)
            ));
        }
        Ok(())
    }

    /// The SGM parameters, when the optimizer is SGM ([`SweepParams::validate_shape`]).
    // `!(x >= 0.0)` on purpose: it also rejects NaN.
    #[expect(
        clippy::neg_cmp_op_on_partial_ord,
        reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
    )]
    fn validate_sgm(&self) -> Result<(), SweepError> {
        let bad = |m: String| Err(SweepError::InvalidParams(m));
        if self.optimizer != Optimizer::Sgm {
            return Ok(());
        }
        if self.sgm_paths != 4 && self.sgm_paths != 8 {
            return bad(format!("sgm_paths must be 4 or 8, got {}", self.sgm_paths));
        }
        if !(self.sgm_p1 >= 0.0 && self.sgm_p2 >= self.sgm_p1) {
            return bad(format!(
                "SGM penalties need 0 <= sgm_p1 <= sgm_p2, got {} and {}",
                self.sgm_p1, self.sgm_p2
            ));
        }
        // The path costs are summed in 16 bits: paths x (largest cost + P2) must fit.
        let max_p2 = self.max_sgm_p2();
        if self.sgm_p2 > max_p2 {
            return bad(format!(
                "sgm_p2 ({}) is too large for {} paths: the summed path costs are 16-bit, which allows P2 <= {max_p2:.2} with tau = {} (P2 <= {} x tau)",
                self.sgm_p2,
                self.sgm_paths,
                self.tau,
                (self.max_sgm_p2() / self.tau)
            ));
        }
        if !(self.sgm_edge >= 0.0) {
            return bad(format!("sgm_edge must be >= 0, got {}", self.sgm_edge));
        }
        if self.num_planes > gpu_types::MAX_SGM_PLANES {
            return bad(format!(
                "optimizer sgm supports at most {} planes, got {}",
                gpu_types::MAX_SGM_PLANES,
                self.num_planes
            ));
        }
        Ok(())
    }

    /// The largest `sgm_p2` whose path sums still fit 16 bits (score units).
    pub fn max_sgm_p2(&self) -> f32 {
        let paths = self.sgm_paths.max(1);
        let per_path = u32::from(u16::MAX) / paths;
        let p2_levels = per_path.saturating_sub(gpu_types::SGM_COST_MAX);
        p2_levels as f32 * self.tau / gpu_types::SGM_COST_MAX as f32
    }

    /// `AllPairs` always scores all pairs; the others follow `pairs`.
    /// The most views besides itself one reference can sweep with under these parameters:
    /// per-pair aggregation holds at most [`gpu_types::MAX_PAIRS`] pairs, all-pairs scoring
    /// at most [`gpu_types::MAX_CAMERAS`] cameras.
    pub fn max_views(&self) -> usize {
        let max_pairs = gpu_types::MAX_PAIRS as usize;
        match (self.aggregation, self.effective_pairs()) {
            (Aggregation::PerPair, PairSet::Reference) => max_pairs,
            // c cameras make c (c - 1) / 2 pairs.
            (Aggregation::PerPair, PairSet::All) => {
                (2..)
                    .take_while(|c| c * (c - 1) / 2 <= max_pairs)
                    .last()
                    .unwrap_or(2)
                    - 1
            }
            (_, PairSet::All) => gpu_types::MAX_CAMERAS as usize - 1,
            (_, PairSet::Reference) => gpu_types::MAX_RIG_CAMERAS as usize - 1,
        }
    }

    /// How many views besides itself each reference takes (`geometry::neighbours` chooses
    /// them): `max_neighbours`, or [`AUTO_NEIGHBOURS`] for 0, at most [`Self::max_views`].
    pub fn neighbour_count(&self) -> usize {
        let wanted = match self.max_neighbours {
            0 => AUTO_NEIGHBOURS,
            n => n as usize,
        };
        wanted.min(self.max_views())
    }

    pub fn effective_pairs(&self) -> PairSet {
        if self.scoring == Scoring::AllPairs {
            PairSet::All
        } else {
            self.pairs
        }
    }

    pub fn hypotheses(&self) -> InverseDepthSweep {
        InverseDepthSweep {
            min_depth_m: self.min_depth_m,
            max_depth_m: self.max_depth_m,
            num_planes: self.num_planes,
        }
    }
}

/// Half-sequence selection codes (the paper's Fig. 7).
pub mod selection {
    /// No clear half: white.
    pub const NONE: u8 = 0;
    /// Left half at least `half_margin` better: red.
    pub const LEFT: u8 = 1;
    /// Right half at least `half_margin` better: green.
    pub const RIGHT: u8 = 2;
    /// Invalid pixel: black.
    pub const INVALID: u8 = 3;

    pub fn colour(code: u8) -> [u8; 3] {
        match code {
            NONE => [255, 255, 255],
            LEFT => [255, 0, 0],
            RIGHT => [0, 255, 0],
            _ => [0, 0, 0],
        }
    }
}

/// Which of a frame set's maps beyond depth and confidence its caller reads: the WGSL engine
/// reads back and unpacks only these (the others come back empty), the CPU engine makes them
/// all. The node asks for cost and selection while someone subscribes to them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WantedMaps {
    /// [`DepthMaps::cost`].
    pub cost: bool,
    /// [`DepthMaps::selection`].
    pub selection: bool,
    /// [`DepthMaps::depth_raw_m`] and [`DepthMaps::visible_cameras`], which no output publishes.
    pub diagnostics: bool,
    /// Whether the caller keeps depth and confidence as maps of its own. Where it does not
    /// (and wants nothing else), the WGSL engine may lend them out of its mapped readback
    /// buffer instead of copying them ([`crate::sweep::references::ReferenceMaps::Lent`]).
    pub floats: bool,
}

impl WantedMaps {
    /// Every map (the default).
    pub const ALL: Self = Self {
        cost: true,
        selection: true,
        diagnostics: true,
        floats: true,
    };
    /// What the outputs publish: all but the diagnostic maps.
    pub const OUTPUTS: Self = Self {
        diagnostics: false,
        ..Self::ALL
    };
}

impl Default for WantedMaps {
    fn default() -> Self {
        Self::ALL
    }
}

/// Everything one sweep produces, all in the reference camera's pixel grid.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMaps {
    /// z along the reference optical axis, metres, NaN where invalid (REP 118).
    pub depth_m: ImageF32,
    /// Depth before the median and the occlusion check (diagnostics; 0 x 0 where the WGSL
    /// engine was told to leave the diagnostic maps out: [`WantedMaps`]).
    pub depth_raw_m: ImageF32,
    /// In [0, 1]; 0 where invalid.
    pub confidence: ImageF32,
    /// The winning (aggregated) score; NaN where no hypothesis was valid (0 x 0 where the
    /// WGSL engine was told the caller does not read it: [`WantedMaps`]).
    pub cost: ImageF32,
    /// [`selection`] codes (empty where the WGSL engine was told the caller does not read
    /// them).
    pub selection: Vec<u8>,
    /// Cameras that see each pixel after the occlusion check, the reference counted
    /// (diagnostics; empty where the WGSL engine leaves the diagnostic maps out).
    pub visible_cameras: Vec<u8>,
}

impl DepthMaps {
    /// Every map 0 x 0.
    pub fn empty() -> Self {
        let empty = || ImageF32 {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        Self {
            depth_m: empty(),
            depth_raw_m: empty(),
            confidence: empty(),
            cost: empty(),
            selection: Vec::new(),
            visible_cameras: Vec::new(),
        }
    }

    pub fn width(&self) -> u32 {
        self.depth_m.width
    }
    pub fn height(&self) -> u32 {
        self.depth_m.height
    }
    pub fn invalid_fraction(&self) -> f64 {
        let n = self.depth_m.data.len().max(1);
        self.depth_m.data.iter().filter(|d| d.is_nan()).count() as f64 / n as f64
    }
}

/// Adds `ms` to stage `name` of `stages` (a stage timed more than once is summed), or appends it.
pub fn add_stage_ms(stages: &mut Vec<(String, f64)>, name: &str, ms: f64) {
    match stages.iter_mut().find(|(n, _)| n == name) {
        Some((_, total)) => *total += ms,
        None => stages.push((name.to_string(), ms)),
    }
}

/// Per-stage timings of one frame set, milliseconds (GPU timestamps where available).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct StageTimings {
    pub stages: Vec<(String, f64)>,
    /// True when the numbers come from GPU timestamp queries, false when from the CPU clock.
    pub gpu_timestamps: bool,
}

/// Checks that the images match the rig.
pub fn check_images<'a>(rig: &Rig, images: impl Into<SetImages<'a>>) -> Result<(), SweepError> {
    let images = images.into();
    if images.len() != rig.cameras.len() {
        return Err(SweepError::ImageCount {
            images: images.len(),
            cameras: rig.cameras.len(),
        });
    }
    for (camera, image) in rig.cameras.iter().zip(images.iter()) {
        let k = &camera.model.intrinsics;
        if image.width() != k.width_px || image.height() != k.height_px || !image.is_whole() {
            return Err(SweepError::ImageSize {
                camera: camera.name.clone(),
                got_w: image.width(),
                got_h: image.height(),
                want_w: k.width_px,
                want_h: k.height_px,
            });
        }
    }
    Ok(())
}
