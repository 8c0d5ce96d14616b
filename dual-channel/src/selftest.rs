//! Start-up self-tests that are not hardware glue (CiA 304 9.5, EN 50325-5 6.4.1.6 NOTE: a
//! channel leaves the safe state only after its own checks passed).
//!
//! - [`march`]: a March C- test of a RAM area (detects stuck-at, transition and coupling
//!   faults between words), written against [`Words`] so it runs on the MCU's RAM and, in the
//!   tests, on a memory model with injected faults.
//! - The signature cross-check of the two CRC implementations is done by the runtime over the
//!   link; [`crc_known_answer`] checks the channel's own CRC-32 against a known answer.
//! - [`check_image`]: the CRC-32 of the firmware image in flash against the value `cargo
//!   xtask` sealed into it after linking ([`image_crc`] computes both).
//! - [`start_up`]: the order of the start-up, the one place both board layers take it from:
//!   every self-test of [`SELF_TESTS`] first, the independent watchdog armed only after all
//!   of them passed.

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

/// The first word of a sealed image's seal (`cargo xtask` writes it with the CRC after
/// linking); an image built otherwise carries zeros there.
pub const SEALED: u32 = 0x5EA1_ED01;

/// Bytes of the seal: [`SEALED`], then the CRC, both little-endian.
pub const SEAL_LEN: usize = 8;

/// The CRC-32 (ISO-HDLC) of a firmware image's flash contents: `code` (from the first byte of
/// flash to the end of the read-only data) then `data` (the load image of the initialised
/// data, which may start a few alignment bytes later: those are not part of the image), the
/// [`SEAL_LEN`] bytes of the seal at offset `seal` in `code` left out. `None` when the seal
/// does not lie inside `code`. The same function seals the image on the host and checks it on
/// the MCU.
pub fn image_crc(code: &[u8], data: &[u8], seal: usize) -> Option<u32> {
    const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    let before = code.get(..seal)?;
    let after = code.get(seal.checked_add(SEAL_LEN)?..)?;
    let mut digest = CRC.digest();
    digest.update(before);
    digest.update(after);
    digest.update(data);
    Some(digest.finalize())
}

/// Why the image check failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageFault {
    /// The image carries no seal: it was not built by `cargo xtask build` (or the seal is
    /// damaged).
    NotSealed,
    /// The seal lies outside the image (a linker script error).
    SealOutside,
    /// The CRC differs from the sealed one: the flash contents changed.
    Mismatch {
        /// The CRC sealed after linking.
        sealed: u32,
        /// The CRC of the flash as it is.
        found: u32,
    },
}

/// Checks the image in flash (as for [`image_crc`]) against its seal.
pub fn check_image(code: &[u8], data: &[u8], seal: usize) -> Result<(), ImageFault> {
    let word = |at: usize| -> Option<u32> {
        let bytes = code.get(at..at.checked_add(4)?)?;
        Some(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    };
    let (Some(marker), Some(sealed)) = (word(seal), seal.checked_add(4).and_then(word)) else {
        return Err(ImageFault::SealOutside);
    };
    if marker != SEALED {
        return Err(ImageFault::NotSealed);
    }
    let found = image_crc(code, data, seal).ok_or(ImageFault::SealOutside)?;
    if found != sealed {
        return Err(ImageFault::Mismatch { sealed, found });
    }
    Ok(())
}

/// A start-up self-test that runs before the independent watchdog is armed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SelfTest {
    /// March C- over RAM ([`march`]). It runs from the reset handler, before RAM is
    /// initialised; here its verdict is read.
    Ram,
    /// The image in flash against its seal ([`check_image`]).
    ImageCrc,
    /// The link CRC against its check value ([`crc_known_answer`]).
    CrcKnownAnswer,
}

/// The self-tests [`start_up`] runs, in this order.
pub const SELF_TESTS: [SelfTest; 3] = [SelfTest::Ram, SelfTest::ImageCrc, SelfTest::CrcKnownAnswer];

/// What a board layer gives [`start_up`]: its self-tests and its independent watchdog.
pub trait StartUp {
    /// The armed watchdog, which the channel loop feeds from then on.
    type Watchdog;
    /// Runs `test` (logging what it found); `false` when it failed.
    fn self_test(&mut self, test: SelfTest) -> bool;
    /// Arms the independent watchdog. Once armed it cannot be stopped but by a reset.
    fn arm_watchdog(self) -> Self::Watchdog;
}

/// The start-up order (EN 50325-5 6.4.1.6 NOTE: a channel leaves the safe state only after
/// its own self-tests passed): every test of [`SELF_TESTS`], then the watchdog.
///
/// Why the self-tests come first rather than the watchdog fed between their chunks: they are
/// loops over fixed ranges (all of RAM, the image in flash, nine bytes) that wait on no
/// peripheral, so they end by construction; a fed watchdog would add a feed point inside
/// each loop and nothing it could catch. What they take grows with the image: the image CRC
/// costs a number of Thumb instructions per byte (counted under QEMU until 2026-12-07,
/// `manual/src/device.md` has the figure), which a grown image could
/// carry past the watchdog's time and into a reset before every start. Until the watchdog is armed the
/// outputs are low (their reset state) and the channel has not joined the bus: a hang there
/// is the safe state, which the other channel sees as a silent link. A test that fails
/// returns it and leaves the watchdog unarmed: the channel stays halted in the safe state
/// until it is powered again, rather than resetting into the same failure over and over. The
/// start-up steps that wait on hardware (the CAN controller's loop-back test) come after,
/// with the watchdog fed between their bursts.
pub fn start_up<B: StartUp>(mut board: B) -> Result<B::Watchdog, SelfTest> {
    for test in SELF_TESTS {
        if !board.self_test(test) {
            return Err(test);
        }
    }
    Ok(board.arm_watchdog())
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::cell::Cell;

    const DATA: [u8; 24] = [0xA5; 24];

    fn sealed_image() -> (Vec<u8>, usize) {
        let mut code: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        let seal = 400;
        code[seal..seal + 4].copy_from_slice(&SEALED.to_le_bytes());
        let crc = image_crc(&code, &DATA, seal).unwrap();
        code[seal + 4..seal + 8].copy_from_slice(&crc.to_le_bytes());
        (code, seal)
    }

    fn mismatch(result: Result<(), ImageFault>) -> bool {
        matches!(result, Err(ImageFault::Mismatch { .. }))
    }

    #[test]
    fn a_sealed_image_passes_and_any_changed_byte_fails() {
        let (code, seal) = sealed_image();
        assert_eq!(check_image(&code, &DATA, seal), Ok(()));
        for at in (0..code.len()).filter(|at| !(seal..seal + 8).contains(at)) {
            let mut damaged = code.clone();
            damaged[at] ^= 0x10;
            assert!(mismatch(check_image(&damaged, &DATA, seal)), "byte {at}");
        }
        for at in 0..DATA.len() {
            let mut data = DATA;
            data[at] ^= 0x01;
            assert!(mismatch(check_image(&code, &data, seal)), "data byte {at}");
        }
        // The CRC itself damaged.
        let mut damaged = code.clone();
        damaged[seal + 5] ^= 1;
        assert!(mismatch(check_image(&damaged, &DATA, seal)));
    }

    #[test]
    fn an_unsealed_image_or_a_seal_outside_it_fails() {
        let (mut code, seal) = sealed_image();
        let end = code.len();
        assert_eq!(
            check_image(&code, &DATA, end - 4),
            Err(ImageFault::SealOutside)
        );
        assert_eq!(image_crc(&code, &DATA, end - 7), None);
        code[seal] = 0;
        assert_eq!(check_image(&code, &DATA, seal), Err(ImageFault::NotSealed));
    }

    /// The seal's bytes do not enter the CRC: sealing does not change what it seals.
    #[test]
    fn the_crc_leaves_the_seal_out() {
        let (code, seal) = sealed_image();
        let mut zeroed = code.clone();
        zeroed[seal..seal + 8].fill(0);
        assert_eq!(
            image_crc(&code, &DATA, seal),
            image_crc(&zeroed, &DATA, seal)
        );
    }

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

    /// A board under simulated time: each self-test takes its time on `clock`, and the
    /// watchdog, once armed, bites when the first feed comes later than its timeout.
    struct SimulatedBoard<'a> {
        clock: &'a Cell<u64>,
        /// How long each test of [`SELF_TESTS`] takes (µs), and whether it passes.
        tests: [(u64, bool); 3],
        log: &'a mut Vec<&'static str>,
    }

    /// The independent watchdog armed at `armed_us`, 20 ms as the hardware layer's.
    struct SimulatedWatchdog {
        armed_us: u64,
    }

    impl SimulatedWatchdog {
        const TIMEOUT_US: u64 = 20_000;

        /// The channel loop's first feed, at `now_us`: `false` when it came too late.
        fn fed_in_time(&self, now_us: u64) -> bool {
            now_us - self.armed_us < Self::TIMEOUT_US
        }
    }

    impl StartUp for SimulatedBoard<'_> {
        type Watchdog = SimulatedWatchdog;
        fn self_test(&mut self, test: SelfTest) -> bool {
            let index = SELF_TESTS.iter().position(|t| *t == test).unwrap();
            let (takes_us, passes) = self.tests[index];
            self.clock.set(self.clock.get() + takes_us);
            self.log.push(match test {
                SelfTest::Ram => "ram",
                SelfTest::ImageCrc => "image crc",
                SelfTest::CrcKnownAnswer => "crc known answer",
            });
            passes
        }
        fn arm_watchdog(self) -> SimulatedWatchdog {
            self.log.push("watchdog");
            SimulatedWatchdog {
                armed_us: self.clock.get(),
            }
        }
    }

    /// EN 50325-5 6.4.1.6 NOTE. Self-tests that together take longer than the watchdog's
    /// time (RAM at 16 MHz before the clock is raised, the image CRC of a grown image) do not
    /// reset the channel: the watchdog is armed after the last of them, and the channel
    /// loop's first feed, 1 ms later, comes in time.
    #[test]
    fn start_up_runs_the_self_tests_before_the_watchdog_is_armed() {
        let clock = Cell::new(0);
        let mut log = Vec::new();
        let board = SimulatedBoard {
            clock: &clock,
            tests: [(120_000, true), (30_000, true), (10, true)],
            log: &mut log,
        };
        let watchdog = start_up(board).expect("every self-test passes");
        assert!(watchdog.fed_in_time(clock.get() + 1_000));
        assert_eq!(log, ["ram", "image crc", "crc known answer", "watchdog"]);
    }

    /// EN 50325-5 6.4.1.6 NOTE. A failed self-test is returned, the tests after it do not run and the watchdog is not
    /// armed: the channel stays halted in the safe state instead of resetting into the same
    /// failure.
    #[test]
    fn start_up_leaves_the_watchdog_unarmed_after_a_failed_self_test() {
        for failing in 0..SELF_TESTS.len() {
            let mut log = Vec::new();
            let mut tests = [(1_000, true); 3];
            tests[failing].1 = false;
            let board = SimulatedBoard {
                clock: &Cell::new(0),
                tests,
                log: &mut log,
            };
            assert_eq!(start_up(board).err(), Some(SELF_TESTS[failing]));
            assert_eq!(log.len(), failing + 1, "{log:?}");
            assert!(!log.contains(&"watchdog"), "{log:?}");
        }
    }
}
