//! Start-up self-tests that are not hardware glue (CiA 304 9.5, EN 50325-5 Annex A.4: a
//! channel leaves the safe state only after its own checks passed).
//!
//! - [`march`]: a March C- test of a RAM area (detects stuck-at, transition and coupling
//!   faults between words), written against [`Words`] so it runs on the MCU's RAM and, in the
//!   tests, on a memory model with injected faults.
//! - The signature cross-check of the two CRC implementations is done by the runtime over the
//!   link; [`crc_known_answer`] checks the channel's own CRC-32 against a known answer.

/// Word-addressed memory under test.
#[allow(clippy::len_without_is_empty)] // reason: a memory under test is never empty; the test reads `len` only
pub trait Words {
    /// Number of words.
    fn len(&self) -> usize;
    /// Reads word `index`.
    fn read(&mut self, index: usize) -> u32;
    /// Writes word `index`.
    fn write(&mut self, index: usize, value: u32);
}

impl Words for [u32] {
    fn len(&self) -> usize {
        <[u32]>::len(self)
    }
    fn read(&mut self, index: usize) -> u32 {
        // `core::hint::black_box` keeps the compiler from proving the value and skipping the
        // read; on the MCU the board layer passes volatile memory instead.
        core::hint::black_box(self[index])
    }
    fn write(&mut self, index: usize, value: u32) {
        self[index] = core::hint::black_box(value);
    }
}

/// Where a RAM test failed: the word index and the pattern expected there.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RamFault {
    /// The word.
    pub index: usize,
    /// The value expected.
    pub expected: u32,
    /// The value read.
    pub read: u32,
}

/// March C- with all-zero and all-one words, then the same with a checkerboard so that
/// adjacent bits in a word are tested against each other:
/// ⇕(w0); ⇑(r0,w1); ⇑(r1,w0); ⇓(r0,w1); ⇓(r1,w0); ⇕(r0). Leaves the area zeroed.
pub fn march(memory: &mut (impl Words + ?Sized)) -> Result<(), RamFault> {
    let len = memory.len();
    for zero in [0u32, 0x5555_5555] {
        let one = !zero;
        for index in 0..len {
            memory.write(index, zero);
        }
        let elements = [
            (zero, one, true),
            (one, zero, true),
            (zero, one, false),
            (one, zero, false),
        ];
        for (from, to, up) in elements {
            for step in 0..len {
                let index = if up { step } else { len - 1 - step };
                expect(memory, index, from)?;
                memory.write(index, to);
            }
        }
        for index in 0..len {
            expect(memory, index, zero)?;
        }
    }
    for index in 0..len {
        memory.write(index, 0);
    }
    Ok(())
}

/// Reads word `index` and compares it with `expected`.
fn expect(memory: &mut (impl Words + ?Sized), index: usize, expected: u32) -> Result<(), RamFault> {
    let read = memory.read(index);
    if read == expected {
        Ok(())
    } else {
        Err(RamFault {
            index,
            expected,
            read,
        })
    }
}

/// The CRC-32 used on the link against its standard check value ("123456789" → CBF43926h).
pub fn crc_known_answer() -> bool {
    const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    CRC.checksum(b"123456789") == 0xCBF4_3926
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A memory model with one injected fault.
    struct Faulty {
        words: Vec<u32>,
        fault: Injected,
    }

    enum Injected {
        /// Bit `bit` of word `index` always reads `value`.
        StuckAt { index: usize, bit: u32, value: bool },
        /// Writing word `aggressor` also writes its value's bit `bit` into `victim`.
        Coupling {
            aggressor: usize,
            victim: usize,
            bit: u32,
        },
        /// Bits `a` and `b` of word `index` are shorted (read as their AND).
        Bridge { index: usize, a: u32, b: u32 },
    }

    impl Words for Faulty {
        fn len(&self) -> usize {
            self.words.len()
        }
        fn read(&mut self, index: usize) -> u32 {
            let mut value = self.words[index];
            match self.fault {
                Injected::StuckAt {
                    index: at,
                    bit,
                    value: high,
                } if at == index => {
                    if high {
                        value |= 1 << bit;
                    } else {
                        value &= !(1 << bit);
                    }
                }
                Injected::Bridge { index: at, a, b } if at == index => {
                    let both = (value >> a) & (value >> b) & 1;
                    value = (value & !(1 << a) & !(1 << b)) | (both << a) | (both << b);
                }
                _ => {}
            }
            value
        }
        fn write(&mut self, index: usize, value: u32) {
            self.words[index] = value;
            if let Injected::Coupling {
                aggressor,
                victim,
                bit,
            } = self.fault
            {
                if aggressor == index {
                    let mask = 1 << bit;
                    self.words[victim] = (self.words[victim] & !mask) | (value & mask);
                }
            }
        }
    }

    #[test]
    fn healthy_memory_passes_and_is_left_zeroed() {
        let mut words = vec![0xDEAD_BEEFu32; 64];
        assert_eq!(march(words.as_mut_slice()), Ok(()));
        assert!(words.iter().all(|&w| w == 0));
    }

    #[test]
    fn stuck_at_coupling_and_bridging_faults_are_found() {
        let faults = [
            Injected::StuckAt {
                index: 7,
                bit: 3,
                value: true,
            },
            Injected::StuckAt {
                index: 0,
                bit: 31,
                value: false,
            },
            Injected::Coupling {
                aggressor: 10,
                victim: 3,
                bit: 0,
            },
            Injected::Coupling {
                aggressor: 2,
                victim: 20,
                bit: 17,
            },
            Injected::Bridge {
                index: 5,
                a: 0,
                b: 1,
            },
        ];
        for fault in faults {
            let mut memory = Faulty {
                words: vec![0; 32],
                fault,
            };
            assert!(march(&mut memory).is_err());
        }
    }

    #[test]
    fn the_link_crc_gives_its_check_value() {
        assert!(crc_known_answer());
    }
}
