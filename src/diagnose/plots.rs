//! The diagnosis' plots (PNG): the residual over time with the mismatch windows, the residual
//! against the feature the named effect depends on, and open-loop paths before and after.

use super::locate::Located;
use crate::physics::effects::{Family, Feature, FitSetting};
use crate::plot::{FONT, ensure_font};
use crate::trace::Sample;
use crate::trace::{Prediction, Trace};
use crate::world::ShapeId;
use anyhow::{Result, anyhow};
use glam::{Vec2, Vec3};
use plotters::prelude::*;
use std::path::Path;

fn err(path: &Path) -> impl Fn(&dyn std::fmt::Display) -> anyhow::Error + '_ {
    move |e| anyhow!("plotting {}: {e}", path.display())
}

fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if lo > hi {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (lo - pad, hi + pad)
}

/// Corrective force (x, y) over time above, short-horizon prediction error below; mismatch
/// windows shaded, where each fold of the cross-validation starts marked.
pub fn residual_over_time(
    path: &Path,
    samples: &[Sample],
    located: &Located,
    fold_starts: &[f64],
) -> Result<()> {
    ensure_font();
    let e = err(path);
    let root = BitMapBackend::new(path, (900, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (top, bottom) = root.split_vertically(320);
    let t_max = samples.iter().map(|s| s.t).fold(1e-3, f64::max);
    let (f_lo, f_hi) = span(
        samples
            .iter()
            .flat_map(|s| [s.force.x as f64, s.force.y as f64]),
    );
    let e_hi = located
        .errors
        .iter()
        .map(|x| x.1 as f64 * 1e3)
        .fold(located.threshold as f64 * 2e3, f64::max);
    let shade = RGBColor(255, 200, 120).mix(0.35);
    let mut chart = ChartBuilder::on(&top)
        .caption("corrective force", (FONT, 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..t_max, f_lo..f_hi)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .y_desc("force (N)")
        .label_style((FONT, 13))
        .draw()
        .map_err(|x| e(&x))?;
    for w in &located.windows {
        chart
            .draw_series([Rectangle::new(
                [(w.t_start, f_lo), (w.t_end, f_hi)],
                shade.filled(),
            )])
            .map_err(|x| e(&x))?;
    }
    chart
        .draw_series(
            fold_starts
                .iter()
                .map(|&t| PathElement::new(vec![(t, f_lo), (t, f_hi)], BLACK.stroke_width(1))),
        )
        .map_err(|x| e(&x))?;
    for (k, (label, get)) in [
        ("x", (|s: &Sample| s.force.x) as fn(&Sample) -> f32),
        ("y", |s: &Sample| s.force.y),
    ]
    .into_iter()
    .enumerate()
    {
        let colour = Palette99::pick(k).to_rgba();
        chart
            .draw_series(LineSeries::new(
                samples.iter().map(|s| (s.t, get(s) as f64)),
                colour.stroke_width(2),
            ))
            .map_err(|x| e(&x))?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&bottom)
        .caption("0.2 s open-loop prediction error (shaded: mismatch windows; line: held-out part starts)", (FONT, 16))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..t_max, 0.0..e_hi)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("error (mm)")
        .label_style((FONT, 13))
        .draw()
        .map_err(|x| e(&x))?;
    for w in &located.windows {
        chart
            .draw_series([Rectangle::new(
                [(w.t_start, 0.0), (w.t_end, e_hi)],
                shade.filled(),
            )])
            .map_err(|x| e(&x))?;
    }
    let threshold = located.threshold as f64 * 1e3;
    chart
        .draw_series([PathElement::new(
            vec![(0.0, threshold), (t_max, threshold)],
            RED.stroke_width(1),
        )])
        .map_err(|x| e(&x))?;
    chart
        .draw_series(
            fold_starts
                .iter()
                .map(|&t| PathElement::new(vec![(t, 0.0), (t, e_hi)], BLACK.stroke_width(1))),
        )
        .map_err(|x| e(&x))?;
    chart
        .draw_series(LineSeries::new(
            located.errors.iter().map(|&(t, v)| (t, v as f64 * 1e3)),
            BLUE.stroke_width(2),
        ))
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// The feature a family's force depends on and the corrective force along that family's
/// direction, per sample: (feature, force).
fn feature(feature: Feature, setting: &FitSetting, s: &Sample) -> (f64, f64) {
    let v = Vec2::new(s.velocity.x, s.velocity.y);
    let f = Vec2::new(s.force.x, s.force.y);
    let against_motion = if v.length() > 1e-4 {
        -f.dot(v.normalize())
    } else {
        0.0
    };
    match feature {
        Feature::SpeedAlongDirection => (
            v.length() as f64,
            setting.force_direction.map_or(0.0, |d| f.dot(d.truncate())) as f64,
        ),
        Feature::DistanceFromAnchor => {
            let a = setting.anchor.unwrap_or(Vec3::ZERO).truncate();
            let d = Vec2::new(s.position.x, s.position.y) - a;
            (
                d.length() as f64,
                if d.length() > 1e-6 {
                    -f.dot(d.normalize()) as f64
                } else {
                    0.0
                },
            )
        }
        Feature::Acceleration => (
            s.acceleration.truncate().length() as f64,
            if s.acceleration.length() > 1e-6 {
                -f.dot(s.acceleration.truncate().normalize()) as f64
            } else {
                0.0
            },
        ),
        Feature::AngularVelocity => (s.angular_velocity.z as f64, s.torque.z as f64),
        // Where the object is along the direction it slid (the longer side of the slid-over area).
        Feature::PositionAlongSlide => {
            let axis = setting
                .region
                .map_or(0, |(lo, hi)| if hi.x - lo.x >= hi.y - lo.y { 0 } else { 1 });
            (s.position[axis] as f64, against_motion as f64)
        }
        Feature::Speed => (v.length() as f64, against_motion as f64),
    }
}

fn feature_labels(feature: Feature) -> (&'static str, &'static str) {
    match feature {
        Feature::SpeedAlongDirection => (
            "speed (m/s)",
            "corrective force along the fitted direction (N)",
        ),
        Feature::DistanceFromAnchor => (
            "distance from the fitted anchor (m)",
            "corrective force towards the anchor (N)",
        ),
        Feature::Acceleration => ("acceleration (m/s^2)", "corrective force against it (N)"),
        Feature::AngularVelocity => ("angular velocity (rad/s)", "corrective torque (N m)"),
        Feature::PositionAlongSlide => (
            "position along the slide, world x or y (m)",
            "corrective force against the motion (N)",
        ),
        Feature::Speed => ("speed (m/s)", "corrective force against the motion (N)"),
    }
}

/// Scatter of the corrective force against the named effect's feature (speed when nothing is named).
pub fn residual_vs_feature(
    path: &Path,
    samples: &[Sample],
    family: Option<&dyn Family>,
    setting: &FitSetting,
) -> Result<()> {
    let kind = family.map_or(Feature::Speed, |f| f.feature());
    ensure_font();
    let e = err(path);
    let points: Vec<(f64, f64)> = samples
        .iter()
        .filter(|s| !s.touching_robot)
        .map(|s| feature(kind, setting, s))
        .collect();
    let (x_lo, x_hi) = span(points.iter().map(|p| p.0));
    let (y_lo, y_hi) = span(points.iter().map(|p| p.1));
    let (x_desc, y_desc) = feature_labels(kind);
    let root = BitMapBackend::new(path, (720, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let title = format!(
        "residual vs feature ({})",
        family.map_or("no effect named", |f| f.name())
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 13))
        .draw()
        .map_err(|x| e(&x))?;
    chart
        .draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, 3, BLUE.mix(0.5).filled())),
        )
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// The tracked path on the table from `from`, with the open-loop predictions from the judged
/// windows before (base model) and after (augmented model).
pub fn paths(
    path: &Path,
    trace: &Trace,
    shape: ShapeId,
    from: f64,
    before: &[Prediction],
    after: &[Prediction],
) -> Result<()> {
    ensure_font();
    let e = err(path);
    let tracked: Vec<(f64, f64)> = (0..trace.states.len())
        .filter(|&k| trace.states[k].time >= from)
        .map(|k| trace.centroid(shape, k))
        .map(|c| (c.x as f64, c.y as f64))
        .collect();
    let every = |p: &[Prediction]| -> Vec<Vec<(f64, f64)>> {
        p.iter()
            .step_by(2)
            .map(|p| p.path.iter().map(|c| (c.x as f64, c.y as f64)).collect())
            .collect()
    };
    let (b, a) = (every(before), every(after));
    let all = tracked
        .iter()
        .chain(b.iter().flatten())
        .chain(a.iter().flatten());
    let (x_lo, x_hi) = span(all.clone().map(|p| p.0));
    let (y_lo, y_hi) = span(all.map(|p| p.1));
    // Equal scales on both axes.
    let half = ((x_hi - x_lo).max(y_hi - y_lo) * 0.5).max(0.02);
    let (cx, cy) = ((x_lo + x_hi) * 0.5, (y_lo + y_hi) * 0.5);
    let root = BitMapBackend::new(path, (640, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "held-out part: tracked path and 1 s open-loop predictions",
            (FONT, 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style((FONT, 13))
        .draw()
        .map_err(|x| e(&x))?;
    type Paths = Vec<Vec<(f64, f64)>>;
    let series: [(&str, RGBAColor, &Paths); 2] = [
        ("before (current model)", RED.mix(0.8), &b),
        ("after (augmented model)", GREEN.mix(0.8), &a),
    ];
    for (label, colour, lines) in series {
        for (k, line) in lines.iter().enumerate() {
            let s = chart
                .draw_series(LineSeries::new(
                    line.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(|x| e(&x))?;
            if k == 0 {
                s.label(label).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            }
        }
    }
    chart
        .draw_series(LineSeries::new(
            tracked.iter().copied(),
            BLACK.stroke_width(3),
        ))
        .map_err(|x| e(&x))?
        .label("tracked")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(3)));
    chart
        .configure_series_labels()
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
