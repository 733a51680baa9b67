//! The named effects' parameters refined on a replay tracked with them. Tracking with a model
//! that lacks the effect lags what the effect does (the visual forces pull the object after it),
//! and a parameter fitted to that lag inherits it; with the effect in the model the tracked motion
//! is closer to the truth. Then objects with no effect of their own whose mismatches another
//! object's effect explains (a box struck by one heavier than modelled slides further than
//! predicted).

use super::study::Study;
use super::{Plan, traced_replay};
use crate::config::{Config, ModelFile};
use crate::diagnose::locate;
use crate::diagnose::refit;
use crate::physics::Effect;
use crate::physics::effects::FitSetting;
use crate::trace::Trace;
use anyhow::{Context, Result};
use std::path::Path;

/// The named effects, each refitted on a replay (`out/named`) tracked with all of them when that
/// worked, as named otherwise.
pub fn refine_named(
    recording: &Path,
    config: &Config,
    out: &Path,
    plan: &Plan,
    studies: &mut [Study],
) -> Result<Vec<Effect>> {
    let named: Vec<Effect> = studies
        .iter()
        .filter_map(|s| s.chosen.as_ref().and_then(|f| f.effect_term.clone()))
        .collect();
    if named.is_empty() {
        return Ok(named);
    }
    plan.say(format!(
        "replaying with the named effect(s) to refine their parameters ({})",
        named.len()
    ));
    let model = ModelFile {
        source: String::new(),
        effects: named,
    };
    let run = traced_replay(recording, &model.apply(config), &out.join("named"), plan)?;
    let retraced = run.trace.as_ref().context("replay kept no trace")?;
    let mut effects = Vec::new();
    for study in studies.iter_mut() {
        refine(retraced, plan, study)?;
        effects.extend(study.chosen.as_ref().and_then(|f| f.effect_term.clone()));
    }
    Ok(effects)
}

/// Refit `study`'s named family on `retraced`, with its direction, anchor and region found again
/// there (or kept where they are not found); keep the refit if it gives an effect.
fn refine(retraced: &Trace, plan: &Plan, study: &mut Study) -> Result<()> {
    let Some(named) = study.chosen.clone() else {
        return Ok(());
    };
    let Some(family) = named.family else {
        return Ok(());
    };
    plan.say(format!("{}: refining {}", study.name, family.name()));
    let (shape, horizon, base) = (study.shape, plan.horizon, &study.setting.base);
    let windows = &study.windows;
    let base_windows = retraced.predict(base, shape, windows, horizon)?;
    let (direction, anchor) = refit::directions(retraced, shape, &base_windows);
    let setting = FitSetting {
        force_direction: direction.or(study.setting.force_direction),
        anchor: anchor.or(study.setting.anchor),
        region: refit::footprint(retraced, shape, windows, horizon).or(study.setting.region),
        ..study.setting.clone()
    };
    // Fitted on every window: the judging was done where the family was named.
    let refined = refit::fit(
        retraced,
        &setting,
        family,
        windows,
        windows,
        horizon,
        &base_windows,
        &base_windows,
    )?;
    if let Some(f) = refined.filter(|f| f.effect_term.is_some()) {
        study.refined_from = Some(named);
        study.chosen = Some(f);
    }
    Ok(())
}

/// Objects with no effect of their own but located mismatches: those that the effects named on
/// other objects explain, and by which.
pub fn explain_by_others(trace: &Trace, model: &ModelFile, studies: &mut [Study]) -> Result<()> {
    let named: Vec<String> = studies
        .iter()
        .filter_map(|s| {
            s.chosen
                .as_ref()
                .map(|f| format!("{} of {}", f.effect, s.name))
        })
        .collect();
    let unexplained = studies
        .iter_mut()
        .filter(|s| s.chosen.is_none() && !s.located.windows.is_empty());
    for study in unexplained {
        let mut physics = trace.physics.clone();
        let others = model
            .effects
            .iter()
            .filter(|e| e.object() != Some(study.name.as_str()));
        physics.effects.extend(others.cloned());
        if physics.effects.is_empty() {
            continue;
        }
        study.explained =
            locate::explained(trace, &study.located, &physics, study.shape, &study.samples)?;
        if !study.explained.is_empty() {
            study.explained_by = Some(named.join(", "));
        }
    }
    Ok(())
}
