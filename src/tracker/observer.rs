//! Observers: what watches ticks without owning them. Metrics, the diagnosis trace, CSV writers,
//! debug renders and the node's outputs implement `Observer`; a driver calls each after every
//! tick with the tracker (read-only), the tick's inputs and its report.

use super::{TickReport, Tracker};
use crate::inputs::TickInputs;
use anyhow::Result;

/// One finished tick, as observers see it.
pub struct Tick<'a> {
    /// 1 for the first tick.
    pub index: usize,
    pub tracker: &'a Tracker,
    pub inputs: &'a TickInputs,
    pub report: &'a TickReport,
}

pub trait Observer {
    /// The tracker before its first tick.
    fn start(&mut self, _tracker: &Tracker) -> Result<()> {
        Ok(())
    }

    /// After every tick.
    fn tick(&mut self, tick: &Tick) -> Result<()>;
}
