//! Line plots of tracking error over time (plotters, bitmap backend, DejaVu Sans embedded so no
//! system font is needed).

use anyhow::{Result, anyhow};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::path::Path;
use std::sync::Once;

pub const FONT: &str = "sans-serif";

pub fn ensure_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // Fails only if the bundled font does not parse; text is then left out, never a panic.
        let _ = register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
}

/// Write `path`: one line per `(label, [(t s, error mm)])`, titled `title`.
pub fn error_over_time(
    path: &Path,
    title: &str,
    lines: &[(String, Vec<(f64, f32)>)],
) -> Result<()> {
    ensure_font();
    let t_max = lines
        .iter()
        .flat_map(|l| l.1.iter().map(|p| p.0))
        .fold(0.0f64, f64::max)
        .max(1e-3);
    // Cap the axis at a few times the median line's peak so one diverging run does not flatten
    // the others (its line leaves the top of the plot).
    let mut peaks: Vec<f32> = lines
        .iter()
        .map(|l| l.1.iter().map(|p| p.1).fold(0.0f32, f32::max))
        .filter(|p| p.is_finite())
        .collect();
    peaks.sort_by(f32::total_cmp);
    let median_peak = peaks.get(peaks.len() / 2).copied().unwrap_or(1.0);
    let e_max =
        (peaks.last().copied().unwrap_or(1.0).min(3.0 * median_peak) * 1.05).max(1.0) as f64;
    let root = BitMapBackend::new(path, (900, 520)).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| anyhow!("plotting {}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..t_max, 0.0..e_max)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("tracking error (mm)")
        .label_style((FONT, 14))
        .draw()
        .map_err(|e| err(&e))?;
    for (k, (label, series)) in lines.iter().enumerate() {
        let colour = Palette99::pick(k).to_rgba();
        chart
            .draw_series(LineSeries::new(
                series
                    .iter()
                    .map(|&(t, e)| (t, (e as f64).min(e_max * 1.2))),
                colour.stroke_width(2),
            ))
            .map_err(|e| err(&e))?
            .label(label.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plot_is_a_png_with_a_line_of_each_colour() {
        let dir = std::env::temp_dir().join(format!("pegs-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p.png");
        let rising: Vec<(f64, f32)> = (0..50).map(|k| (k as f64 * 0.1, k as f32)).collect();
        let flat: Vec<(f64, f32)> = (0..50).map(|k| (k as f64 * 0.1, 5.0)).collect();
        error_over_time(
            &path,
            "test",
            &[("rising".into(), rising), ("flat".into(), flat)],
        )
        .unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (900, 520));
        // Both series colours appear (plus white background and black text).
        let has = |c: RGBAColor| img.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count() > 100;
        assert!(has(Palette99::pick(0).to_rgba()) && has(Palette99::pick(1).to_rgba()));
        let dark = img.pixels().filter(|p| p.0.iter().all(|&v| v < 60)).count();
        assert!(
            dark > 500,
            "axis text and frame should be drawn ({dark} dark pixels)"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
