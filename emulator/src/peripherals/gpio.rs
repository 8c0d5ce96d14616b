//! General-purpose I/O ports of the STM32F405 (RM0090 8): MODER, OTYPER, OSPEEDR, PUPDR,
//! IDR, ODR, BSRR, LCKR (with its lock key sequence), AFRL and AFRH, accessible by byte,
//! half-word and word (RM0090 8.4).
//!
//! Pins are seen from outside: an input pin's level is what the board drives on it
//! ([`Gpio::drive`]) or, undriven, what its pull resistor gives; an undriven pin without pull
//! reads low, as if the board held it down. An output pin's level is observable
//! ([`Gpio::output_level`]). Alternate functions route the pin to a peripheral model (USART,
//! CAN); their levels are those models' business, so IDR reads such a pin as the board drives
//! it.

use super::{AccessError, Context, Peripheral};

/// Base address of GPIOA (RM0090 2.3, Table 1); each port is [`SIZE`] further.
pub const GPIOA_BASE: u32 = 0x4002_0000;
/// The size of one port's block.
pub const SIZE: u32 = 0x400;

/// A port of the STM32F405RG this project uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    /// GPIOA.
    A,
    /// GPIOB.
    B,
    /// GPIOC.
    C,
}

impl Port {
    /// The port's base address.
    pub fn base(self) -> u32 {
        GPIOA_BASE + SIZE * self.index()
    }

    fn index(self) -> u32 {
        match self {
            Port::A => 0,
            Port::B => 1,
            Port::C => 2,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Port::A => "GPIOA (RM0090 8)",
            Port::B => "GPIOB (RM0090 8)",
            Port::C => "GPIOC (RM0090 8)",
        }
    }
}

/// MODER values (RM0090 8.4.1).
const MODE_OUTPUT: u32 = 0b01;
const MODE_ANALOG: u32 = 0b11;
/// PUPDR values (RM0090 8.4.4).
const PULL_UP: u32 = 0b01;
/// LCKR.LCKK (RM0090 8.4.8).
const LCKK: u32 = 1 << 16;

/// One GPIO port.
#[derive(Clone, Debug)]
pub struct Gpio {
    port: Port,
    moder: u32,
    otyper: u32,
    ospeedr: u32,
    pupdr: u32,
    odr: u32,
    afr: [u32; 2],
    /// LCKR's lock bits once the key sequence has frozen them (until reset).
    locked: u32,
    locked_active: bool,
    /// The lock key sequence's step (0: none) and the LCK bits written with it.
    lock_step: u8,
    lock_bits: u32,
    /// What the board drives on each pin (`None`: nothing).
    driven: [Option<bool>; 16],
}

impl Gpio {
    /// The port after reset (RM0090 8.4: port A has the debug pins PA13-PA15 in alternate
    /// function with pull-ups and PA13 at high speed, port B PB3 and PB4 likewise, the other
    /// ports all inputs).
    pub fn new(port: Port) -> Gpio {
        let (moder, ospeedr, pupdr) = match port {
            Port::A => (0xA800_0000, 0x0C00_0000, 0x6400_0000),
            Port::B => (0x0000_0280, 0x0000_00C0, 0x0000_0100),
            Port::C => (0, 0, 0),
        };
        Gpio {
            port,
            moder,
            otyper: 0,
            ospeedr,
            pupdr,
            odr: 0,
            afr: [0; 2],
            locked: 0,
            locked_active: false,
            lock_step: 0,
            lock_bits: 0,
            driven: [None; 16],
        }
    }

    /// The port after a system reset (RM0090 8.4): its registers back to their reset values;
    /// what the board drives on its pins stays driven.
    pub fn after_reset(&self) -> Gpio {
        Gpio {
            driven: self.driven,
            ..Gpio::new(self.port)
        }
    }

    /// The port's name and base.
    pub fn port(&self) -> Port {
        self.port
    }

    /// Drives pin `pin` from outside at `level` (`None`: stops driving it).
    pub fn drive(&mut self, pin: usize, level: Option<bool>) {
        if let Some(driven) = self.driven.get_mut(pin) {
            *driven = level;
        }
    }

    fn mode(&self, pin: usize) -> u32 {
        (self.moder >> (2 * pin)) & 3
    }

    fn pull_up(&self, pin: usize) -> bool {
        (self.pupdr >> (2 * pin)) & 3 == PULL_UP
    }

    /// The level the output driver puts on `pin`, when it drives it: `Some` for a
    /// push-pull output, and for an open-drain output writing 0 (RM0090 8.3.10).
    pub fn output_level(&self, pin: usize) -> Option<bool> {
        if pin >= 16 || self.mode(pin) != MODE_OUTPUT {
            return None;
        }
        let high = self.odr & (1 << pin) != 0;
        let open_drain = self.otyper & (1 << pin) != 0;
        if open_drain && high { None } else { Some(high) }
    }

    /// The level on `pin`: the output driver's, else the board's, else the pull-up's, else
    /// low.
    pub fn level(&self, pin: usize) -> bool {
        self.output_level(pin)
            .or_else(|| self.driven.get(pin).copied().flatten())
            .unwrap_or_else(|| self.pull_up(pin))
    }

    /// IDR (RM0090 8.4.5): the pins' levels; a pin in analog mode reads 0 (RM0090 8.3.12).
    fn idr(&self) -> u32 {
        (0..16)
            .filter(|&pin| self.mode(pin) != MODE_ANALOG && self.level(pin))
            .fold(0, |idr, pin| idr | (1 << pin))
    }

    /// The register at word offset `offset`.
    fn register(&self, offset: u32) -> Option<u32> {
        Some(match offset {
            0x00 => self.moder,
            0x04 => self.otyper,
            0x08 => self.ospeedr,
            0x0C => self.pupdr,
            0x10 => self.idr(),
            0x14 => self.odr,
            // BSRR is write-only: it reads as 0 (RM0090 8.4.7).
            0x18 => 0,
            0x1C => {
                let lckk = if self.locked_active { LCKK } else { 0 };
                self.locked | lckk
            }
            0x20 => self.afr[0],
            0x24 => self.afr[1],
            _ => return None,
        })
    }

    /// Bits of a configuration register that the lock freezes: one bit per pin (`width` 1),
    /// two (`width` 2) or four.
    fn frozen(&self, width: u32, first_pin: u32) -> u32 {
        if !self.locked_active {
            return 0;
        }
        let field = (1u32 << width) - 1;
        (0..32 / width)
            .filter(|i| self.locked & (1 << (first_pin + i)) != 0)
            .fold(0, |mask, i| mask | (field << (i * width)))
    }

    fn write_register(&mut self, offset: u32, value: u32, written: u32) {
        let merge = |old: u32, frozen: u32| {
            let writable = written & !frozen;
            (old & !writable) | (value & writable)
        };
        match offset {
            0x00 => self.moder = merge(self.moder, self.frozen(2, 0)),
            0x04 => self.otyper = merge(self.otyper, self.frozen(1, 0) | 0xFFFF_0000),
            0x08 => self.ospeedr = merge(self.ospeedr, self.frozen(2, 0)),
            0x0C => self.pupdr = merge(self.pupdr, self.frozen(2, 0)),
            0x14 => self.odr = merge(self.odr, 0xFFFF_0000),
            0x18 => {
                // Set has priority over reset when both are written (RM0090 8.4.7).
                let set = value & written & 0xFFFF;
                let reset = (value & written) >> 16;
                self.odr = (self.odr & !reset) | set;
            }
            0x1C => self.write_lckr(value),
            0x20 => self.afr[0] = merge(self.afr[0], self.frozen(4, 0)),
            0x24 => self.afr[1] = merge(self.afr[1], self.frozen(4, 8)),
            _ => {}
        }
    }

    /// The lock key sequence (RM0090 8.4.8): LCKK 1, 0, 1 with the same LCK bits, then a
    /// read. Any other write starts it again.
    fn write_lckr(&mut self, value: u32) {
        if self.locked_active {
            return;
        }
        let bits = value & 0xFFFF;
        let lckk = value & LCKK != 0;
        self.lock_step = match (self.lock_step, lckk) {
            (0, true) => {
                self.lock_bits = bits;
                1
            }
            (1, false) if bits == self.lock_bits => 2,
            (2, true) if bits == self.lock_bits => 3,
            (_, true) => {
                self.lock_bits = bits;
                1
            }
            _ => 0,
        };
    }

    fn width_error(&self, offset: u32, size: u32) -> AccessError {
        AccessError::Width {
            block: self.port.name(),
            offset,
            size,
        }
    }
}

impl Peripheral for Gpio {
    fn name(&self) -> &'static str {
        self.port.name()
    }

    fn read(&mut self, _ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        if !matches!(size, 1 | 2 | 4) || offset % size != 0 {
            return Err(self.width_error(offset, size));
        }
        let word = offset & !3;
        let value = self.register(word).ok_or(AccessError::Unmodelled {
            block: self.port.name(),
            offset,
        })?;
        if word == 0x1C && self.lock_step == 3 {
            // The read that completes the key sequence.
            self.locked = self.lock_bits;
            self.locked_active = true;
            self.lock_step = 0;
        }
        let shift = 8 * (offset & 3);
        let mask = if size == 4 {
            u32::MAX
        } else {
            (1 << (8 * size)) - 1
        };
        Ok((value >> shift) & mask)
    }

    fn write(
        &mut self,
        _ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError> {
        if !matches!(size, 1 | 2 | 4) || offset % size != 0 {
            return Err(self.width_error(offset, size));
        }
        let word = offset & !3;
        if self.register(word).is_none() {
            return Err(AccessError::Unmodelled {
                block: self.port.name(),
                offset,
            });
        }
        // LCKR's sequence is defined for word writes only.
        if word == 0x1C && size != 4 {
            return Err(self.width_error(offset, size));
        }
        let shift = 8 * (offset & 3);
        let lane = if size == 4 {
            u32::MAX
        } else {
            ((1u32 << (8 * size)) - 1) << shift
        };
        self.write_register(word, value << shift, lane);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::Clocks;

    const CTX: Context = Context {
        now: 0,
        clocks: Clocks::RESET,
    };

    #[test]
    fn rm0090_8_4_reset_values_of_ports_a_b_c() {
        let mut a = Gpio::new(Port::A);
        let mut b = Gpio::new(Port::B);
        let mut c = Gpio::new(Port::C);
        assert_eq!(a.read(&CTX, 0x00, 4).unwrap(), 0xA800_0000);
        assert_eq!(a.read(&CTX, 0x0C, 4).unwrap(), 0x6400_0000);
        assert_eq!(b.read(&CTX, 0x00, 4).unwrap(), 0x0000_0280);
        assert_eq!(b.read(&CTX, 0x08, 4).unwrap(), 0x0000_00C0);
        assert_eq!(c.read(&CTX, 0x00, 4).unwrap(), 0);
    }

    #[test]
    fn rm0090_8_4_5_input_pins_read_the_board_the_pull_up_or_low() {
        let mut c = Gpio::new(Port::C);
        assert_eq!(c.read(&CTX, 0x10, 4).unwrap(), 0);
        c.drive(0, Some(true));
        assert_eq!(c.read(&CTX, 0x10, 4).unwrap(), 1);
        c.write(&CTX, 0x0C, 4, PULL_UP << 4).unwrap();
        assert_eq!(c.read(&CTX, 0x10, 4).unwrap(), 0b101);
        // Analog mode reads 0.
        c.write(&CTX, 0x00, 4, MODE_ANALOG).unwrap();
        assert_eq!(c.read(&CTX, 0x10, 4).unwrap(), 0b100);
    }

    #[test]
    fn rm0090_8_4_7_bsrr_sets_and_resets_with_set_first_and_reads_zero() {
        let mut c = Gpio::new(Port::C);
        c.write(&CTX, 0x00, 4, MODE_OUTPUT << 2).unwrap();
        assert_eq!(c.output_level(1), Some(false));
        c.write(&CTX, 0x18, 4, 1 << 1).unwrap();
        assert_eq!(c.output_level(1), Some(true));
        assert_eq!(c.read(&CTX, 0x10, 4).unwrap() & 2, 2);
        c.write(&CTX, 0x18, 4, (1 << 17) | (1 << 1)).unwrap();
        assert_eq!(c.output_level(1), Some(true));
        c.write(&CTX, 0x18, 4, 1 << 17).unwrap();
        assert_eq!(c.output_level(1), Some(false));
        assert_eq!(c.read(&CTX, 0x18, 4).unwrap(), 0);
        // The reset half-word alone.
        c.write(&CTX, 0x18, 4, 1 << 1).unwrap();
        c.write(&CTX, 0x1A, 2, 1 << 1).unwrap();
        assert_eq!(c.output_level(1), Some(false));
    }

    #[test]
    fn rm0090_8_3_10_open_drain_high_releases_the_pin() {
        let mut c = Gpio::new(Port::C);
        c.write(&CTX, 0x00, 4, MODE_OUTPUT).unwrap();
        c.write(&CTX, 0x04, 4, 1).unwrap();
        c.write(&CTX, 0x14, 4, 1).unwrap();
        assert_eq!(c.output_level(0), None);
        assert!(!c.level(0));
        c.drive(0, Some(true));
        assert!(c.level(0));
    }

    #[test]
    fn rm0090_8_4_8_the_lock_key_sequence_freezes_the_configuration_until_reset() {
        let mut c = Gpio::new(Port::C);
        c.write(&CTX, 0x1C, 4, LCKK | 1).unwrap();
        c.write(&CTX, 0x1C, 4, 1).unwrap();
        c.write(&CTX, 0x1C, 4, LCKK | 1).unwrap();
        c.read(&CTX, 0x1C, 4).unwrap();
        assert_eq!(c.read(&CTX, 0x1C, 4).unwrap(), LCKK | 1);
        c.write(&CTX, 0x00, 4, 0b0101).unwrap();
        // Pin 0 is frozen as input, pin 1 became an output.
        assert_eq!(c.read(&CTX, 0x00, 4).unwrap(), 0b0100);
    }

    #[test]
    fn rm0090_8_4_a_wrong_lock_sequence_locks_nothing() {
        let mut c = Gpio::new(Port::C);
        c.write(&CTX, 0x1C, 4, LCKK | 1).unwrap();
        c.write(&CTX, 0x1C, 4, 2).unwrap();
        c.write(&CTX, 0x1C, 4, LCKK | 1).unwrap();
        c.read(&CTX, 0x1C, 4).unwrap();
        assert_eq!(c.read(&CTX, 0x1C, 4).unwrap() & LCKK, 0);
    }

    #[test]
    fn rm0090_8_4_byte_access_and_unmodelled_offsets() {
        let mut c = Gpio::new(Port::C);
        c.write(&CTX, 0x21, 1, 0x7).unwrap();
        assert_eq!(c.read(&CTX, 0x20, 4).unwrap(), 0x700);
        assert!(c.read(&CTX, 0x28, 4).is_err());
    }
}
