//! The independent watchdog (RM0090 21, IWDG): the key register, write-protected prescaler
//! and reload registers whose updates take LSI cycles (PVU, RVU), the 12-bit down-counter
//! clocked by the LSI and the reset request it makes when it runs out.
//!
//! Modelled (RM0090 21.3, 21.4):
//! - KR: 0xCCCC starts the watchdog, counting down from 0xFFF (21.3.1, "the counter starts
//!   counting down from the reset value of 0xFFF"); 0xAAAA reloads the counter from RLR;
//!   0x5555 unlocks PR and RLR, any other value locks them again (21.3.2). KR reads 0.
//! - PR and RLR: written only while unlocked and while their update flag (PVU, RVU) is
//!   clear; a written value reaches the VDD domain [`UPDATE_LSI_CYCLES`] LSI cycles later
//!   (21.4.4: "takes up to 5 RC 40 kHz cycles"; the model takes five cycles of its LSI);
//!   reads return the VDD domain's value, the one the counter uses.
//! - Timeout: (RL + 1) × 4 × 2^PR LSI cycles after a reload (PR 6 and 7 both divide by 256),
//!   which gives the manual's minimum and maximum timeout table (21.3.3, Table 107). A new
//!   prescaler reaching the VDD domain while the counter runs rescales the ticks left.
//! - Expiry: [`Iwdg::reset_requested`] becomes true; the CPU side resets the system and sets
//!   RCC_CSR.IWDGRSTF. The watchdog cannot be stopped except by that reset.
//!
//! The LSI: the STM32F405 datasheet (DS8626, "LSI oscillator characteristics") gives
//! 17 kHz minimum, 32 kHz typical and 47 kHz maximum; the model runs at the typical value,
//! [`LSI_HZ`]. Not modelled: the hardware watchdog option (WDG_SW), the debug freeze
//! (DBG_IWDG_STOP), the phase between the APB clock and the LSI (the manual's one-period
//! uncertainty). Registers take half-word and word accesses (21.4); bytes are refused.

use super::{AccessError, Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// The IWDG block's base address.
pub const BASE: u32 = 0x4000_3000;
/// The IWDG block's size.
pub const SIZE: u32 = 0x400;
/// The LSI frequency the model uses: the datasheet's typical value.
pub const LSI_HZ: u32 = 32_000;
/// LSI cycles a PR or RLR write takes to reach the VDD domain (RM0090 21.4.4).
pub const UPDATE_LSI_CYCLES: u64 = 5;

const NAME: &str = "IWDG (RM0090 21)";

/// The counter's value when the watchdog starts, and RLR's reset value.
const COUNTER_RESET: u32 = 0xFFF;

/// A PR or RLR value on its way to the VDD domain.
#[derive(Clone, Copy, Debug)]
struct Update {
    value: u32,
    done_at: Nanos,
}

/// The independent watchdog model.
#[derive(Clone, Debug)]
pub struct Iwdg {
    unlocked: bool,
    prescaler: u32,
    reload: u32,
    prescaler_update: Option<Update>,
    reload_update: Option<Update>,
    /// When the counter runs out (`None`: not started).
    expiry: Option<Nanos>,
    reset: bool,
    now: Nanos,
}

impl Default for Iwdg {
    fn default() -> Self {
        Self::new()
    }
}

/// LSI cycles of one counter tick for prescaler field `prescaler`: 4 × 2^PR, at most 256.
fn divider(prescaler: u32) -> u64 {
    4 << prescaler.min(6)
}

impl Iwdg {
    /// The watchdog after reset: stopped, PR = 0, RLR = 0xFFF, locked.
    pub fn new() -> Iwdg {
        Iwdg {
            unlocked: false,
            prescaler: 0,
            reload: COUNTER_RESET,
            prescaler_update: None,
            reload_update: None,
            expiry: None,
            reset: false,
            now: 0,
        }
    }

    /// Whether the counter ran out: the system must be reset (RM0090 21.3.1).
    pub fn reset_requested(&self) -> bool {
        self.reset
    }

    /// Whether the watchdog has been started.
    pub fn is_running(&self) -> bool {
        self.expiry.is_some()
    }

    /// The time `count + 1` ticks take from `from` at the VDD domain's prescaler.
    fn after_ticks(&self, from: Nanos, count: u32) -> Nanos {
        from + Clocks::nanos((u64::from(count) + 1) * divider(self.prescaler), LSI_HZ)
    }

    fn next_due(&self) -> Option<Nanos> {
        let expiry = if self.reset { None } else { self.expiry };
        [
            expiry,
            self.prescaler_update.map(|update| update.done_at),
            self.reload_update.map(|update| update.done_at),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    fn run_until(&mut self, now: Nanos) {
        while let Some(due) = self.next_due() {
            if due > now {
                break;
            }
            if let Some(update) = self.prescaler_update.filter(|update| update.done_at == due) {
                self.prescaler_update = None;
                if let Some(expiry) = self.expiry.filter(|_| !self.reset) {
                    // Rescale the ticks left to the new prescaler.
                    let old_tick = Clocks::nanos(divider(self.prescaler), LSI_HZ);
                    let ticks_left = (expiry - due).div_ceil(old_tick.max(1));
                    self.prescaler = update.value;
                    let new_tick = divider(self.prescaler);
                    self.expiry = Some(due + Clocks::nanos(ticks_left * new_tick, LSI_HZ));
                } else {
                    self.prescaler = update.value;
                }
            } else if let Some(update) = self.reload_update.filter(|update| update.done_at == due) {
                self.reload_update = None;
                self.reload = update.value;
            } else if self.expiry == Some(due) {
                self.reset = true;
            }
        }
        self.now = self.now.max(now);
    }

    fn write_key(&mut self, key: u32) {
        match key {
            0xCCCC => {
                if self.expiry.is_none() {
                    self.expiry = Some(self.after_ticks(self.now, COUNTER_RESET));
                }
                self.unlocked = false;
            }
            0xAAAA => {
                if self.expiry.is_some() && !self.reset {
                    self.expiry = Some(self.after_ticks(self.now, self.reload));
                }
                self.unlocked = false;
            }
            0x5555 => self.unlocked = true,
            _ => self.unlocked = false,
        }
    }

    fn update_time(&self) -> Nanos {
        self.now + Clocks::nanos(UPDATE_LSI_CYCLES, LSI_HZ)
    }
}

impl Peripheral for Iwdg {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        self.run_until(ctx.now);
        if size == 1 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x00 => Ok(0),
            0x04 => Ok(self.prescaler),
            0x08 => Ok(self.reload),
            0x0C => Ok(u32::from(self.prescaler_update.is_some())
                | (u32::from(self.reload_update.is_some()) << 1)),
            _ => Err(AccessError::Unmodelled {
                block: NAME,
                offset,
            }),
        }
    }

    fn write(
        &mut self,
        ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError> {
        self.run_until(ctx.now);
        if size == 1 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x00 => self.write_key(value & 0xFFFF),
            0x04 => {
                if self.unlocked && self.prescaler_update.is_none() {
                    self.prescaler_update = Some(Update {
                        value: value & 0x7,
                        done_at: self.update_time(),
                    });
                }
            }
            0x08 => {
                if self.unlocked && self.reload_update.is_none() {
                    self.reload_update = Some(Update {
                        value: value & 0xFFF,
                        done_at: self.update_time(),
                    });
                }
            }
            // SR is read-only.
            0x0C => {}
            _ => {
                return Err(AccessError::Unmodelled {
                    block: NAME,
                    offset,
                });
            }
        }
        Ok(())
    }

    fn advance(&mut self, ctx: &Context) {
        self.run_until(ctx.now);
    }

    fn next_event(&self, _ctx: &Context) -> Option<Nanos> {
        self.next_due()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KR: u32 = 0x00;
    const PR: u32 = 0x04;
    const RLR: u32 = 0x08;
    const SR: u32 = 0x0C;
    const MILLISECOND: Nanos = 1_000_000;

    type Bench = crate::peripherals::bench::Bench<Iwdg>;

    impl Bench {
        fn new() -> Bench {
            Bench::on(Iwdg::new(), Clocks::RESET)
        }

        /// Unlocks, writes PR and RLR, waits for both updates.
        fn configure(&mut self, prescaler: u32, reload: u32) {
            self.write(KR, 0x5555);
            self.write(PR, prescaler);
            self.write(RLR, reload);
            self.wait(Clocks::nanos(UPDATE_LSI_CYCLES, LSI_HZ));
            assert_eq!(self.read(SR), 0);
        }
    }

    #[test]
    fn rm0090_21_4_registers_after_reset() {
        let mut bench = Bench::new();
        assert_eq!(bench.read(KR), 0);
        assert_eq!(bench.read(PR), 0);
        assert_eq!(bench.read(RLR), 0xFFF);
        assert_eq!(bench.read(SR), 0);
        assert!(!bench.model.is_running());
        bench.wait(3_600_000 * MILLISECOND);
        assert!(!bench.model.reset_requested(), "not started: no reset");
    }

    #[test]
    fn rm0090_21_3_1_start_counts_down_from_0xfff_and_requests_a_reset_at_zero() {
        let mut bench = Bench::new();
        bench.write(KR, 0xCCCC);
        // 4096 ticks of 4 LSI cycles at 32 kHz: Table 107's maximum for PR = 0.
        bench.wait(512 * MILLISECOND - 1);
        assert!(!bench.model.reset_requested());
        bench.wait(1);
        assert!(bench.model.reset_requested());
    }

    #[test]
    fn rm0090_21_3_3_timeouts_match_table_107_at_32_khz() {
        // (PR, RL, timeout in microseconds): Table 107's minimum and maximum columns.
        let table = [
            (0, 0x000, 125),
            (0, 0xFFF, 512_000),
            (1, 0x000, 250),
            (3, 0xFFF, 4_096_000),
            (6, 0x000, 8_000),
            (6, 0xFFF, 32_768_000),
            (7, 0xFFF, 32_768_000),
        ];
        for (prescaler, reload, micros) in table {
            let mut bench = Bench::new();
            bench.configure(prescaler, reload);
            bench.write(KR, 0xCCCC);
            bench.write(KR, 0xAAAA);
            let timeout = micros * 1_000;
            bench.wait(timeout - 1);
            assert!(
                !bench.model.reset_requested(),
                "PR {prescaler} RL {reload:#x}"
            );
            bench.wait(1);
            assert!(
                bench.model.reset_requested(),
                "PR {prescaler} RL {reload:#x}"
            );
        }
    }

    #[test]
    fn rm0090_21_3_1_reload_key_restarts_the_count_from_rlr() {
        let mut bench = Bench::new();
        bench.configure(0, 0x0FF);
        bench.write(KR, 0xCCCC);
        // 256 ticks of 125 µs: 32 ms.
        for _ in 0..10 {
            bench.wait(30 * MILLISECOND);
            bench.write(KR, 0xAAAA);
        }
        assert!(!bench.model.reset_requested());
        bench.wait(32 * MILLISECOND);
        assert!(bench.model.reset_requested());
    }

    #[test]
    fn rm0090_21_3_2_pr_and_rlr_are_write_protected_until_0x5555() {
        let mut bench = Bench::new();
        bench.write(PR, 5);
        bench.write(RLR, 5);
        bench.wait(MILLISECOND);
        assert_eq!(bench.read(PR), 0);
        assert_eq!(bench.read(RLR), 0xFFF);
        assert_eq!(bench.read(SR), 0, "no update started");
    }

    #[test]
    fn rm0090_21_3_2_any_other_key_restores_the_protection() {
        for key in [0xAAAA, 0x1234] {
            let mut bench = Bench::new();
            bench.write(KR, 0x5555);
            bench.write(KR, key);
            bench.write(PR, 5);
            bench.wait(MILLISECOND);
            assert_eq!(bench.read(PR), 0, "after key {key:#x}");
        }
    }

    #[test]
    fn rm0090_21_4_4_updates_take_lsi_cycles_and_show_in_pvu_rvu() {
        let mut bench = Bench::new();
        bench.write(KR, 0x5555);
        bench.write(PR, 3);
        bench.write(RLR, 0x123);
        assert_eq!(bench.read(SR), 0b11, "PVU and RVU");
        assert_eq!(bench.read(PR), 0, "the VDD domain still has the old value");
        assert_eq!(bench.read(RLR), 0xFFF);
        bench.wait(Clocks::nanos(UPDATE_LSI_CYCLES, LSI_HZ) - 1);
        assert_eq!(bench.read(SR), 0b11);
        bench.wait(1);
        assert_eq!(bench.read(SR), 0);
        assert_eq!(bench.read(PR), 3);
        assert_eq!(bench.read(RLR), 0x123);
    }

    #[test]
    fn rm0090_21_4_2_a_write_while_the_update_flag_is_set_is_ignored() {
        let mut bench = Bench::new();
        bench.write(KR, 0x5555);
        bench.write(RLR, 0x100);
        bench.write(RLR, 0x200);
        bench.wait(MILLISECOND);
        assert_eq!(bench.read(RLR), 0x100);
    }

    #[test]
    fn rm0090_21_4_3_reload_uses_the_vdd_domain_value() {
        let mut bench = Bench::new();
        bench.configure(0, 0x0FF);
        bench.write(KR, 0xCCCC);
        bench.write(KR, 0x5555);
        bench.write(RLR, 0xFFF);
        // Reloaded before the new RLR reached the VDD domain: 256 ticks, 32 ms.
        bench.write(KR, 0xAAAA);
        bench.wait(32 * MILLISECOND);
        assert!(bench.model.reset_requested());
    }

    #[test]
    fn rm0090_21_4_2_a_new_prescaler_slows_the_ticks_left() {
        let mut bench = Bench::new();
        bench.write(KR, 0xCCCC);
        bench.wait(256 * MILLISECOND);
        // About 2048 ticks left; from PR = 1 on they take 250 µs each instead of 125 µs.
        bench.write(KR, 0x5555);
        bench.write(PR, 1);
        bench.wait(511 * MILLISECOND);
        assert!(!bench.model.reset_requested());
        bench.wait(MILLISECOND);
        assert!(bench.model.reset_requested());
    }

    #[test]
    fn rm0090_21_3_1_the_watchdog_cannot_be_stopped() {
        let mut bench = Bench::new();
        bench.write(KR, 0xCCCC);
        bench.write(KR, 0x0000);
        bench.write(KR, 0xCCCC);
        bench.wait(512 * MILLISECOND);
        assert!(bench.model.reset_requested());
    }

    #[test]
    fn rm0090_21_4_next_event_is_the_expiry() {
        let mut bench = Bench::new();
        bench.write(KR, 0xCCCC);
        assert_eq!(
            bench.model.next_event(&bench.ctx()),
            Some(512 * MILLISECOND)
        );
    }

    #[test]
    fn rm0090_21_4_byte_accesses_and_holes_are_refused() {
        let mut bench = Bench::new();
        let ctx = bench.ctx();
        assert!(matches!(
            bench.model.write(&ctx, KR, 1, 0xCC),
            Err(AccessError::Width { .. })
        ));
        assert!(bench.model.write(&ctx, KR, 2, 0xCCCC).is_ok());
        assert!(matches!(
            bench.model.read(&ctx, 0x10, 4),
            Err(AccessError::Unmodelled { offset: 0x10, .. })
        ));
    }
}
