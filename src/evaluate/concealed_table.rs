//! `pegs scenario concealed`: every concealed scenario generated, diagnosed and checked against
//! its hidden truth; the README's table of results is written by this, never by hand.

use crate::config::Config;
use crate::diagnose::report::{ObjectReport, Report};
use crate::diagnose::{DiagnoseOptions, diagnose};
use crate::scenario::{concealed, generate};
use anyhow::{Context, Result};
use glam::Vec2;
use serde::Serialize;
use std::path::Path;

pub const START: &str = "<!-- concealed-table:start -->";
pub const END: &str = "<!-- concealed-table:end -->";

/// A diagnosis judged against the scenario's hidden truth.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    pub scenario: String,
    pub truth: String,
    pub named: String,
    pub estimate: Option<f32>,
    pub truth_value: Option<f32>,
    /// |estimate - truth| / truth.
    pub relative_error: Option<f32>,
    /// Mismatch windows (start, end, object).
    pub windows: Vec<(f64, f64, String)>,
    pub region_ok: Option<bool>,
    pub open_loop_before_mm: f32,
    pub open_loop_after_mm: f32,
    pub right_effect: bool,
    pub within_25_percent: bool,
    pub located: bool,
    pub halved: bool,
}

impl Verdict {
    pub fn passed(&self) -> bool {
        self.right_effect && self.within_25_percent && self.located && self.halved
    }
}

/// Judge `report` (of the box) against scenario `name`'s truth.
pub fn judge(name: &str, report: &Report) -> Verdict {
    let truth = concealed::truth(name);
    let object: Option<&ObjectReport> = report.objects.iter().find(|o| o.object == "box");
    let named = object.map_or("none".to_string(), |o| o.effect.clone());
    let estimate = object.and_then(|o| o.parameters.first()).map(|p| p.value);
    let truth_value = truth.parameter.map(|p| p.1);
    let relative_error = match (estimate, truth_value) {
        (Some(e), Some(t)) => Some((e.abs() - t).abs() / t),
        _ => None,
    };
    // Where the effect shows, in any object's motion (a heavy box shows in the boxes it strikes).
    let windows: Vec<(f64, f64, String)> = report
        .mismatch
        .iter()
        .map(|m| (m.t_start, m.t_end, m.object.clone()))
        .collect();
    let region_ok = truth.region.map(|(c, h)| {
        // The placed patch: at least half of it is truly patch (it is known only where the box
        // went, so it may be smaller than the truth), and every located mismatch reaches into it.
        let fitted = |n: &str| {
            object
                .and_then(|o| o.parameters.iter().find(|p| p.name == n))
                .map(|p| p.value)
        };
        let (Some(cx), Some(cy), Some(hx), Some(hy)) = (
            fitted("center_x"),
            fitted("center_y"),
            fitted("half_size_x"),
            fitted("half_size_y"),
        ) else {
            return false;
        };
        let (lo, hi) = (Vec2::new(cx - hx, cy - hy), Vec2::new(cx + hx, cy + hy));
        let overlap = (hi.min(c + h) - lo.max(c - h)).max(Vec2::ZERO);
        let inside = overlap.x * overlap.y >= 0.5 * (hi - lo).x * (hi - lo).y;
        let reached = object.is_some_and(|o| {
            o.mismatch.iter().all(|m| {
                let (a, b) = (Vec2::from(m.footprint_min), Vec2::from(m.footprint_max));
                (b.min(hi) - a.max(lo)).min_element() > 0.0
            })
        });
        inside && reached
    });
    let (before, after) = object.map_or((0.0, 0.0), |o| {
        (o.before.open_loop_error_mm, o.after.open_loop_error_mm)
    });
    let right_effect = named == truth.effect.unwrap_or("none");
    let control = truth.effect.is_none();
    Verdict {
        scenario: name.to_string(),
        truth: truth.effect.unwrap_or("none").to_string(),
        named,
        estimate,
        truth_value,
        relative_error,
        // Windows while the box moves after a strike (the effects act only on a moving box).
        located: control || (!windows.is_empty() && region_ok.unwrap_or(true)),
        windows,
        region_ok,
        open_loop_before_mm: before,
        open_loop_after_mm: after,
        within_25_percent: control || relative_error.is_some_and(|e| e <= 0.25),
        halved: control || after <= 0.5 * before,
        right_effect,
    }
}

/// Generate and diagnose `names` at `width` x `height` into `out`; the verdicts and a Markdown table.
pub fn run(
    out: &Path,
    names: &[String],
    width: u32,
    height: u32,
    progress: bool,
) -> Result<(Vec<Verdict>, String)> {
    let mut verdicts = Vec::new();
    for name in names {
        let dir = out.join(name);
        let opts = generate::GenerateOptions {
            width,
            height,
            seconds: concealed::SECONDS,
            ..Default::default()
        };
        generate::generate(name, &dir, &opts).with_context(|| format!("generating {name}"))?;
        let config = Config::load(&dir.join("config.yaml"))?;
        let report = diagnose(
            &dir.join("recording"),
            &config,
            &dir.join("diagnosis"),
            DiagnoseOptions {
                progress,
                ..Default::default()
            },
        )?;
        let verdict = judge(name, &report);
        if progress {
            eprintln!(
                "{name}: named {} (truth {}), passed: {}",
                verdict.named,
                verdict.truth,
                verdict.passed()
            );
        }
        verdicts.push(verdict);
    }
    std::fs::write(
        out.join("verdicts.json"),
        serde_json::to_string_pretty(&verdicts)?,
    )?;
    let mut rows = vec![
        format!("Concealed physics, 3 cameras at {width}x{height}; each diagnosis is judged by cross-validation over three folds of consecutive windows. Generated by `pegs scenario concealed`."),
        String::new(),
        "| scenario | hidden effect | named | estimate (truth) | error | mismatch windows (s) | 1 s open-loop error before -> after (mm) | pass |".to_string(),
        "| --- | --- | --- | --- | ---: | --- | --- | --- |".to_string(),
    ];
    for v in &verdicts {
        let estimate = match (v.estimate, v.truth_value) {
            (Some(e), Some(t)) => format!("{e:.4} ({t:.4})"),
            _ => "-".into(),
        };
        let windows: Vec<String> = v
            .windows
            .iter()
            .map(|w| {
                format!(
                    "{:.1}-{:.1}{}",
                    w.0,
                    w.1,
                    if w.2 == "box" {
                        String::new()
                    } else {
                        format!(" ({})", w.2)
                    }
                )
            })
            .collect();
        rows.push(format!(
            "| {} | {} | {} | {} | {} | {} | {:.1} -> {:.1} | {} |",
            v.scenario,
            concealed::description(&v.scenario),
            v.named,
            estimate,
            v.relative_error
                .map_or("-".into(), |e| format!("{:.0} %", e * 100.0)),
            if windows.is_empty() {
                "-".into()
            } else {
                windows.join(", ")
            },
            v.open_loop_before_mm,
            v.open_loop_after_mm,
            if v.passed() { "yes" } else { "no" }
        ));
    }
    Ok((verdicts, rows.join("\n")))
}
