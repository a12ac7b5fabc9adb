//! The engine parameters, each declared once: the field of [`SweepParams`] it sets, its node
//! parameter name, type, default, command-line option, range and description. From this one
//! list come
//!
//! * `SweepParams::default()` (the engine's defaults),
//! * the engine parameters of the node's parameter table ([`super::param_table`]: declared on
//!   the parameter services, documented in docs/node.md, live: a change applies from the next
//!   frame set),
//! * the engine options of `demo`, `eval` and `bench` ([`super::EngineOptions`]),
//! * the range checks of every value set by either ([`super::ParamSpec::coerce`]), and
//! * the copy of a parameter set into [`SweepParams`] ([`super::apply_to_sweep`], beside the
//!   set in `set.rs`: the set is made from the table this list is part of).
//!
//! The checks across parameters and against the rig's shape stay with the engine
//! ([`SweepParams::validate`]) and [`super::checks`].

use std::sync::LazyLock;

use super::spec::{ParamRange, ParamSpec};
use super::ParamError;
use crate::ros::param_value::{ParamKind, ParamValue};
use crate::sweep::gpu_types::{MAX_BEST_N, MAX_HALF_BEST_N, MAX_RIG_CAMERAS};
use crate::sweep::{
    Aggregation, Cost, Optimizer, PairSet, Prefilter, Scoring, SweepParams, WindowMode, MAX_PLANES,
};

/// The command-line option of an engine parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flag {
    /// `--NAME VALUE`.
    Long(&'static str),
    /// `--NAME WxH` sets two parameters: this one is its W.
    Width(&'static str),
    /// ... and this one its H.
    Height(&'static str),
}

impl Flag {
    /// The option's name (after `--`).
    pub fn long(self) -> &'static str {
        match self {
            Flag::Long(name) | Flag::Width(name) | Flag::Height(name) => name,
        }
    }
}

/// One engine parameter: its spec in the node's table, its command-line option, and how it
/// reads and writes its field of [`SweepParams`].
#[derive(Debug, Clone)]
pub struct EngineParam {
    pub spec: ParamSpec,
    pub flag: Flag,
    /// The field as a parameter value.
    pub get: fn(&SweepParams) -> ParamValue,
    /// Sets the field from a value of the parameter's kind (one that passed
    /// [`ParamSpec::coerce`]).
    pub set: fn(&mut SweepParams, &ParamValue) -> Result<(), ParamError>,
}

/// A [`SweepParams`] field type as a parameter value.
trait Field: Sized {
    const KIND: ParamKind;
    fn to_value(&self) -> ParamValue;
    fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError>;
}

fn not_a(name: &str, value: &ParamValue) -> ParamError {
    ParamError::NotA {
        name: name.to_string(),
        kind: value.kind(),
    }
}

impl Field for f64 {
    const KIND: ParamKind = ParamKind::Double;
    fn to_value(&self) -> ParamValue {
        ParamValue::Double(*self)
    }
    fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError> {
        value.as_f64().ok_or_else(|| not_a(name, value))
    }
}

impl Field for f32 {
    const KIND: ParamKind = ParamKind::Double;
    /// The double of the f32's shortest decimal form: 0.01f32 is the parameter 0.01, not
    /// 0.009999999776482582.
    fn to_value(&self) -> ParamValue {
        ParamValue::Double(self.to_string().parse().unwrap_or(f64::from(*self)))
    }
    fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError> {
        value
            .as_f64()
            .map(|v| v as f32)
            .ok_or_else(|| not_a(name, value))
    }
}

impl Field for u32 {
    const KIND: ParamKind = ParamKind::Int;
    fn to_value(&self) -> ParamValue {
        ParamValue::Int(i64::from(*self))
    }
    fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError> {
        let v = value.as_i64().ok_or_else(|| not_a(name, value))?;
        u32::try_from(v).map_err(|_| ParamError::NotU32 {
            name: name.to_string(),
            value: v,
        })
    }
}

impl Field for bool {
    const KIND: ParamKind = ParamKind::Bool;
    fn to_value(&self) -> ParamValue {
        ParamValue::Bool(*self)
    }
    fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError> {
        value.as_bool().ok_or_else(|| not_a(name, value))
    }
}

/// The engine's enums are parameters of type string, named as serde names their variants
/// (`best_n_of_m`); their range is every variant.
macro_rules! enum_field {
    ($($ty:ty),*) => {$(
        impl Field for $ty {
            const KIND: ParamKind = ParamKind::String;
            fn to_value(&self) -> ParamValue {
                ParamValue::String(variant_name(self))
            }
            fn from_value(name: &str, value: &ParamValue) -> Result<Self, ParamError> {
                let text = value.as_str().ok_or_else(|| not_a(name, value))?;
                serde_json::from_value(serde_json::Value::String(text.to_string())).map_err(
                    |_| ParamError::NotAVariant {
                        name: name.to_string(),
                        value: text.to_string(),
                    },
                )
            }
        }
    )*};
}

enum_field!(
    Cost,
    Scoring,
    PairSet,
    Aggregation,
    WindowMode,
    Optimizer,
    Prefilter
);

/// The serde (snake_case) name of an enum variant.
fn variant_name<T: serde::Serialize + std::fmt::Debug>(v: &T) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::String(name)) => name,
        _ => format!("{v:?}"),
    }
}

/// Every variant of an engine enum, by its parameter name.
fn variants<T: clap::ValueEnum + serde::Serialize + std::fmt::Debug>() -> ParamRange {
    ParamRange::OneOf(T::value_variants().iter().map(variant_name).collect())
}

/// The declaration: one line per engine parameter,
/// `field: type = default, "node name", CLI flag, range, "description";`.
macro_rules! engine_params {
    ($($field:ident: $ty:ty = $default:expr, $name:literal, $flag:expr, $range:expr,
       $description:literal;)*) => {
        impl Default for SweepParams {
            fn default() -> Self {
                Self { $($field: $default,)* }
            }
        }

        fn declarations() -> Vec<EngineParam> {
            vec![$(EngineParam {
                spec: ParamSpec {
                    name: $name,
                    kind: <$ty as Field>::KIND,
                    default: Field::to_value(&{
                        let default: $ty = $default;
                        default
                    }),
                    range: $range,
                    description: $description,
                    read_only: false,
                    required: false,
                },
                flag: $flag,
                get: |p| Field::to_value(&p.$field),
                set: |p, value| {
                    p.$field = <$ty as Field>::from_value($name, value)?;
                    Ok(())
                },
            }),*]
        }
    };
}

use Flag::{Height, Long, Width};

engine_params! {
    min_depth_m: f64 = 0.5, "min_depth", Long("min-depth"), ParamRange::above(0.0),
        "Nearest depth swept, metres (must be < max_depth).";
    max_depth_m: f64 = 10.0, "max_depth", Long("max-depth"), ParamRange::above(0.0),
        "Farthest depth swept, metres.";
    num_planes: u32 = 64, "num_planes", Long("planes"), ParamRange::ints(2, i64::from(MAX_PLANES)),
        "Number of depth planes, uniform in inverse depth (with optimizer sgm at most 1024). Neighbouring planes more than 2 px apart in a reference's widest view lose much of the depth: warned, with the count that puts them 1 px apart.";
    // The cost, the window and the SGM penalties were chosen together on the evaluation sets
    // (docs/quality.md, CHANGELOG.md).
    cost: Cost = Cost::AdCensus, "cost", Long("cost"), variants::<Cost>(),
        "Pair matching cost: truncated colour SSD, 5x5 census (blind to gain and offset), or their mean.";
    scoring: Scoring = Scoring::BestHalfSequence, "scoring", Long("scoring"), variants::<Scoring>(),
        "How the camera pairs of one hypothesis combine into one score.";
    pairs: PairSet = PairSet::Reference, "pairs", Long("pairs"), variants::<PairSet>(),
        "Camera pairs that are scored: the reference against each other camera, or all pairs.";
    best_n: u32 = 2, "best_n", Long("best-n"), ParamRange::ints(1, i64::from(MAX_BEST_N)),
        "n of best n of m.";
    half_best_n: u32 = 2, "half_best_n", Long("half-best-n"),
        ParamRange::ints(0, i64::from(MAX_HALF_BEST_N)),
        "Best half-sequence with per-pair aggregation: each half scores the mean of its n best pairs, n at most half its pairs rounded up (0 = all pairs, the paper's rule).";
    aggregation: Aggregation = Aggregation::PerPair, "aggregation", Long("aggregation"),
        variants::<Aggregation>(),
        "Where the windows aggregate: the scored cost, each half, or each camera pair.";
    window_width: u32 = 5, "window_width", Width("window"), ParamRange::ints(1, 33),
        "Aggregation window width, pixels (1 = none; shiftable windows: 1 or even).";
    window_height: u32 = 5, "window_height", Height("window"), ParamRange::ints(1, 33),
        "Aggregation window height, pixels (1 = none; shiftable windows: 1 or even).";
    window_mode: WindowMode = WindowMode::Centred, "window_mode", Long("window-mode"),
        variants::<WindowMode>(),
        "Window placement: the best of the four corner windows (the paper), or one centred window.";
    tau: f32 = 100.0, "tau", Long("tau"), ParamRange::above(0.0),
        "Truncation of the colour SSD (sum over RGB of squared 0..255 differences); the scale of every cost (a census cost of tau = all 24 bits differ).";
    max_cost: f32 = 100.0, "max_cost", Long("max-cost"), ParamRange::above(0.0),
        "A best score above this makes the pixel invalid.";
    keep_range_ends: bool = false, "keep_range_ends", Long("keep-range-ends"), ParamRange::Any,
        "Keep the depth of pixels whose best plane is the first or the last (min_depth, max_depth): a surface nearer or farther than the range lands there, so by default they are invalid.";
    subpixel: bool = true, "subpixel", Long("subpixel"), ParamRange::Any,
        "Sub-pixel depth between the planes (a parabola through the winner's and its neighbours' scores).";
    subpixel_v_fit: bool = false, "subpixel_v_fit", Long("subpixel-v-fit"), ParamRange::Any,
        "With subpixel: a V (equiangular line) instead of the parabola; exact for SGM's piecewise linear path costs, fewer layers in one depth map, but fused models come out slightly worse (docs/quality.md).";
    subpixel_refine: bool = false, "subpixel_refine", Long("subpixel-refine"), ParamRange::Any,
        "With subpixel: a fine local sweep of 5 hypotheses a quarter plane apart around each pixel's depth, windows following the smoothed depth (both engines).";
    median: bool = true, "median", Long("median"), ParamRange::Any,
        "3x3 median filter on the depth map.";
    // Issue 29: measured on the evaluation sets (docs/quality.md).
    // Stop 83: a raw pair swept rectified (docs/speed.md "Two cameras").
    rectify_pairs: bool = true, "rectify_pairs", Long("rectify-pairs"),
        ParamRange::Any,
        "CPU engine: a pair of cameras whose images are not rectified (lens distortion, views turned toward each other) is swept as a rectified pair: both images resampled once onto one rectified grid, as stereo_image_proc does, the depth mapped back onto the reference's pixels (a raw 752x480 pair 13 % faster on 2 cores, and more precise: docs/engine.md); false: the raw images are sampled through the lens model at every plane, as the WGSL engine always does.";
    joint_median_radius: u32 = 0, "joint_median_radius", Long("joint-median-radius"),
        ParamRange::ints(0, 15),
        "Colour-weighted median of the depth after the sweep, guided by the reference image (puts fattened depth edges back on the colour edges, fills invalid pixels): window radius, pixels (4: 9x9, docs/quality.md); 0 = off (the default: it costs the demo about a quarter of its time).";
    joint_median_colour: f32 = 20.0, "joint_median_colour", Long("joint-median-colour"),
        ParamRange::above(0.0),
        "Colour-weighted median: the L1 RGB difference (0..765) at which a neighbour's weight falls to 1/e.";
    joint_median_fill: bool = true, "joint_median_fill", Long("joint-median-fill"),
        ParamRange::Any,
        "Colour-weighted median: invalid pixels take their window's median where they have valid neighbours of their own colour (false: they stay invalid).";
    min_visible_cameras: u32 = 2, "min_visible_cameras", Long("min-visible"),
        ParamRange::ints(0, i64::from(MAX_RIG_CAMERAS)),
        "Pixels seen by fewer cameras (the reference counted) are invalid; 0 or 1 disables.";
    occlusion_tolerance: f32 = 0.01, "occlusion_tolerance", Long("occlusion-tolerance"),
        ParamRange::at_least(0.0),
        "Relative depth tolerance of the occlusion z-test: a pixel counts as hidden from a camera only where a surface there is nearer by more than this share of its depth and by more than two plane steps (a neighbour a fraction of a plane away is no occluder).";
    half_margin: f32 = 0.1, "half_margin", Long("half-margin"),
        ParamRange::Double { min: 0.0, max: 1.0, min_exclusive: false, max_exclusive: true },
        "A half is clearly better when its score is below (1 - margin) times the other's, and lower by at least margin x 25 (the noise floor of an RGB SSD).";
    optimizer: Optimizer = Optimizer::Sgm, "optimizer", Long("optimizer"),
        variants::<Optimizer>(),
        "Depth selection: local winner-take-all (the paper) or semi-global matching over a u16 cost volume.";
    // SGM penalties chosen on the evaluation sets themselves (Tsukuba, Teddy, Laundry;
    // docs/quality.md, CHANGELOG.md).
    sgm_p1: f32 = 20.0, "sgm_p1", Long("sgm-p1"), ParamRange::at_least(0.0),
        "SGM penalty for a one-plane step between neighbours, score units (those of tau).";
    sgm_p2: f32 = 250.0, "sgm_p2", Long("sgm-p2"), ParamRange::at_least(0.0),
        "SGM penalty for a larger step, score units (>= sgm_p1; paths x (tau + P2) must fit 16 bits: P2 <= 7 x tau with 8 paths).";
    sgm_paths: u32 = 8, "sgm_paths", Long("sgm-paths"), ParamRange::ints(4, 8),
        "SGM path directions: 4 (rows and columns) or 8 (plus diagonals).";
    sgm_edge: f32 = 10.0, "sgm_edge", Long("sgm-edge"), ParamRange::closed(0.0, 255.0),
        "SGM: colour step (largest RGB difference between path neighbours, 0..255) at which P2 is halved (P2 / (1 + step / sgm_edge), at least P1); 0 = constant P2.";
    coarse_to_fine: bool = true, "coarse_to_fine", Long("coarse-to-fine"), ParamRange::Any,
        "From 48 planes: sweep at half resolution (every other plane; itself coarse to fine from 96 planes) first, then each row only over the planes its neighbourhood found there, plus 3 on each side.";
    max_neighbours: u32 = 0, "max_neighbours", Long("max-neighbours"),
        ParamRange::ints(0, i64::from(MAX_RIG_CAMERAS)),
        "Views (cameras besides itself) each reference sweeps with, at most: of the cameras that see at least 10 % of its view, the best for depth (triangulation angles near 5 degrees and overlap, alternately from each half of the rig, a spread of directions); 0 = 8. At most 16 with per-pair aggregation.";
    // Issue 52: chosen on real-camera pairs, the lab sets, and the lab rigs given real cameras'
    // radiometry (docs/quality.md).
    prefilter: Prefilter = Prefilter::Auto, "prefilter", Long("prefilter"),
        variants::<Prefilter>(),
        "What the colour term of the cost compares: each image's horizontal derivative (gradient: cameras that differ in offset, exposure or vignetting match; census and SGM edges still see the raw grey), the images as they are (none: lab sets with equal exposures and clean images), or auto: gradient for a pair of cameras, and for more once their images are a camera's (median step between neighbouring columns at most 5 grey levels) or their mean brightness differs by more than 6 %; none for renders of high-contrast texture.";
    uniqueness: f32 = 0.0, "uniqueness", Long("uniqueness"),
        ParamRange::Double { min: 0.0, max: 1.0, min_exclusive: false, max_exclusive: true },
        "Pixels whose winner does not beat its best rival on the matching costs by this share are invalid ((rival - best) / (rival + 1); with SGM: SGM's winner against the best plane more than 1.5 px of shift away): a repeated pattern gives no depth instead of wrong depth, but weakly textured surfaces lose pixels too (docs/engine.md); 0 = none.";
    ambiguity: f32 = 0.15, "ambiguity", Long("ambiguity"),
        ParamRange::Double { min: 0.0, max: 1.0, min_exclusive: false, max_exclusive: true },
        "With SGM: the confidence of a pixel whose winner beats its best rival on the matching costs (as uniqueness measures it) by less than this share is scaled by share / ambiguity: a repeated pattern or a blank surface gives depth with low confidence, not confident wrong depth; 0 = SGM's confidence alone.";
}

static ENGINE_PARAMS: LazyLock<Vec<EngineParam>> = LazyLock::new(declarations);

/// Every engine parameter, in the order of the docs.
pub fn engine_params() -> &'static [EngineParam] {
    &ENGINE_PARAMS
}

/// The declaration of the engine parameter `name`.
pub fn engine_param(name: &str) -> Option<&'static EngineParam> {
    engine_params().iter().find(|p| p.spec.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;

    #[test]
    fn every_field_reads_back_what_it_was_set_to() {
        let mut p = SweepParams::default();
        for e in engine_params() {
            assert_eq!((e.get)(&p), e.spec.default, "{}", e.spec.name);
            (e.set)(&mut p, &e.spec.default).unwrap();
        }
        assert_eq!(p, SweepParams::default());
        // The declared defaults print as written (f32 fields too).
        let tolerance = engine_param("occlusion_tolerance").unwrap();
        assert_eq!(tolerance.spec.default, ParamValue::Double(0.01));
        let scoring = engine_param("scoring").unwrap();
        assert_eq!(
            scoring.spec.range,
            ParamRange::one_of(&["sssd", "all_pairs", "best_n_of_m", "best_half_sequence"])
        );
    }

    /// Where the engine checks a bound itself ([`SweepParams::validate`]), the declared range
    /// says the same: the ends pass, one step outside fails.
    #[test]
    fn declared_ranges_agree_with_the_engine() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(16, 16));
        let rig = crate::synthetic::row_rig(5, 0.1, model, 2).unwrap();
        let check = |name: &str, value: ParamValue| {
            let mut p = SweepParams {
                pairs: PairSet::All,
                optimizer: Optimizer::Wta,
                scoring: Scoring::BestNOfM,
                ..SweepParams::default()
            };
            let e = engine_param(name).unwrap();
            (e.set)(&mut p, &value).unwrap();
            let table = e.spec.coerce(&value).is_ok();
            let engine = p.validate(&rig).is_ok();
            assert_eq!(
                table, engine,
                "{name} = {value}: table {table}, engine {engine}"
            );
        };
        for (name, min, max) in [
            ("num_planes", 2, 4096),
            ("window_width", 1, 33),
            ("window_height", 1, 33),
            ("best_n", 1, i64::from(MAX_BEST_N)),
            ("half_best_n", 0, i64::from(MAX_HALF_BEST_N)),
        ] {
            for v in [min, max, max + 1] {
                check(name, ParamValue::Int(v));
            }
            if min > 0 {
                check(name, ParamValue::Int(min - 1));
            }
        }
        for (name, values) in [
            ("min_depth", &[0.0, 0.01][..]),
            ("tau", &[0.0, 1.0]),
            ("max_cost", &[0.0, 1.0]),
            ("occlusion_tolerance", &[-0.1, 0.0]),
            ("half_margin", &[-0.1, 0.0, 0.99, 1.0]),
        ] {
            for v in values {
                check(name, ParamValue::Double(*v));
            }
        }
    }
}
