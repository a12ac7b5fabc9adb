//! `eval`'s printed table: the header and one row per dataset.

use super::metrics::Metrics;
use crate::datasets::Dataset;

/// The table header printed by [`super::run`].
pub fn table_header() -> String {
    format!(
        "{:<34} {:<17} {:>5} {:>9} {:>6} {:>7} {:>7} {:>7} {:>6} {:>6} {:>7} {:>12} {:>8} {:>9}  {}",
        "dataset",
        "layout",
        "views",
        "size",
        "planes",
        "bad>.5",
        "bad>1",
        "bad>2",
        "rms",
        "rms<2",
        "signed",
        "bad>1(valid)",
        "invalid",
        "ms",
        "notes"
    )
}

/// One table row.
pub fn table_row(
    dataset: &Dataset,
    metrics: Option<&Metrics>,
    invalid_all: f64,
    ms: f64,
) -> String {
    table_row_as(&dataset.name, dataset, metrics, invalid_all, ms)
}

/// One table row under another name (the peer's, beside the dataset's own).
pub fn table_row_as(
    name: &str,
    dataset: &Dataset,
    metrics: Option<&Metrics>,
    invalid_all: f64,
    ms: f64,
) -> String {
    let (w, h) = dataset.reference_size();
    let pct = |v: f64| format!("{v:.2}%");
    let px = |v: f64| format!("{v:.3}");
    let none = || "-".to_string();
    let (precision, bad1, bad2, bad1_valid, invalid, notes) = match metrics {
        Some(Metrics::Disparity(m)) => (
            [
                pct(m.bad05),
                px(m.rms),
                px(m.rms_inliers),
                format!("{:+.3}", m.mean_signed),
            ],
            pct(m.bad1),
            pct(m.bad2),
            pct(m.bad1_valid),
            pct(m.invalid),
            match m.confidence_ranking {
                Some(r) => format!(
                    "bad>1(valid) confident half {:.2}% vs rest {:.2}%",
                    r.bad1_confident_half, r.bad1_rest
                ),
                None => String::new(),
            },
        ),
        Some(Metrics::Depth(m)) => (
            [none(), none(), none(), none()],
            "-".into(),
            "-".into(),
            "-".into(),
            pct(m.invalid),
            format!(
                "absrel {:.4}, within 1% {:.2}%, within 5% {:.2}%{}",
                m.mean_abs_rel,
                m.within_1pct,
                m.within_5pct,
                match m.confidence_ranking {
                    Some(r) => format!(
                        "; valid off >1%: confident half {:.2}% vs all {:.2}%, off >5%: {:.2}% vs {:.2}%",
                        r.off1_confident_half, r.off1_all_valid, r.off5_confident_half, r.off5_all_valid
                    ),
                    None => String::new(),
                }
            ),
        ),
        None => (
            [none(), none(), none(), none()],
            "-".into(),
            "-".into(),
            "-".into(),
            pct(100.0 * invalid_all),
            "no ground truth (invalid = whole image)".into(),
        ),
    };
    format!(
        "{:<34} {:<17} {:>5} {:>9} {:>6} {:>7} {:>7} {:>7} {:>6} {:>6} {:>7} {:>12} {:>8} {:>9.1}  {}",
        dataset.name,
        dataset.layout.name(),
        dataset.rig.cameras.len(),
        format!("{w}x{h}"),
        dataset.params.num_planes,
        precision[0],
        bad1,
        bad2,
        precision[1],
        precision[2],
        precision[3],
        bad1_valid,
        invalid,
        ms,
        notes
    )
    .replacen(&format!("{:<34}", dataset.name), &format!("{name:<34}"), 1)
}
