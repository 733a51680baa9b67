//! Judging pegs against ground truth on synthetic scenarios, and writing what it measured into
//! the README: the tracking table (`scenario_table`), the concealed-physics table
//! (`concealed_table`: diagnoses checked against the hidden truth) and the ablation sweep
//! (`ablation`). Jobs on top of replay and diagnose; nothing here is used by them.

pub mod ablation;
pub mod concealed_table;
pub mod scenario_table;

use anyhow::{Context, Result, bail};
use std::path::Path;

/// Replace the text between the `start` and `end` marker lines of `path` with `text`.
pub fn write_between(path: &Path, start: &str, end: &str, table: &str) -> Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (Some(a), Some(b)) = (text.find(start), text.find(end)) else {
        bail!("{} has no {start} ... {end} block", path.display())
    };
    if b < a {
        bail!("{}: markers out of order", path.display());
    }
    let updated = format!("{}{start}\n{table}\n{}", &text[..a], &text[b..]);
    std::fs::write(path, updated).with_context(|| format!("cannot write {}", path.display()))
}
