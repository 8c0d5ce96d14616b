//! A model on a test bench: the virtual time and the clocks held, registers read and written
//! as the CPU does (word accesses), time advanced as the CPU side advances it. One bench for
//! every model's tests.

use super::{Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// `model` at `now`, on `clocks`.
pub(crate) struct Bench<P> {
    /// The model under test.
    pub model: P,
    /// Virtual time now.
    pub now: Nanos,
    /// The clock frequencies the model sees.
    pub clocks: Clocks,
}

impl<P: Peripheral> Bench<P> {
    /// `model` at time 0 on `clocks`.
    pub fn on(model: P, clocks: Clocks) -> Self {
        Bench {
            model,
            now: 0,
            clocks,
        }
    }

    /// What an access lends the model now.
    pub fn ctx(&self) -> Context {
        Context {
            now: self.now,
            clocks: self.clocks,
        }
    }

    /// Reads the register at `offset` (it must be modelled).
    pub fn read(&mut self, offset: u32) -> u32 {
        let ctx = self.ctx();
        self.model
            .read(&ctx, offset, 4)
            .expect("a modelled register")
    }

    /// Writes the register at `offset` (it must be modelled).
    pub fn write(&mut self, offset: u32, value: u32) {
        let ctx = self.ctx();
        self.model
            .write(&ctx, offset, 4, value)
            .expect("a modelled register");
    }

    /// Lets `duration` of virtual time pass.
    pub fn wait(&mut self, duration: Nanos) {
        self.now += duration;
        let ctx = self.ctx();
        self.model.advance(&ctx);
    }
}
