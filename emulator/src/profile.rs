//! Where an emulated MCU's instructions go: a profile kept while it runs, counted at each
//! translated block's start with the block's instruction count (the count virtual time uses),
//! and read afterwards against the image's function symbols.
//!
//! Three things are kept:
//!
//! - **Per block**: the instructions executed in each translated block, by its first address;
//!   [`Profile::functions`] sums them by the function symbol that holds the block (a flat
//!   profile: a function's own instructions, not its callees').
//! - **Per activation**: the instructions from one wake-up of the core (from WFI or WFE) to
//!   the next, with the [`Marker`]s whose function was entered meanwhile. An activation is the
//!   whole cost of what woke the core: the interrupt handlers, the channel loop's iteration if
//!   the loop ran, and the wait it then sets up. One that entered no
//!   marker ran interrupt handlers only (a link byte into or out of the USART's ring, say).
//! - **The deepest stack**: the lowest main stack pointer seen at a block's start since the
//!   profile began (a leaf function's own frame below it is not seen; exception frames are,
//!   at their handler's first block).
//!
//! A profile costs a hash-map look-up per block; a machine keeps none unless asked
//! ([`crate::cpu::Machine::start_profile`]).

use std::collections::HashMap;

use crate::image::Symbols;

/// A function whose entry tells what an activation did, found in the image's symbols by a
/// part of its demangled name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Marker {
    /// Its name in reports.
    pub label: &'static str,
    /// The demangled function name (the hash left out), or a part of it that only it has.
    pub symbol: &'static str,
    /// Whether [`Marker::symbol`] is the whole name (an interrupt handler's), not a part.
    pub whole: bool,
}

/// The markers of the shipped images (`board::hw`, `dual_channel`, `shared::simplecan`), in
/// bit order; an image without a marker's function (the CANopen Safety images have no
/// SimpleCAN packet code) never enters it. Each function is kept out of line in the images
/// (`#[inline(never)]` on the target): a copy inlined into a caller would run without its
/// entry, and the activations that ran it would be counted as something else.
pub const MARKERS: [Marker; 16] = [
    Marker {
        label: "loop",
        symbol: "dual_channel::channel_loop::ChannelLoop::service",
        whole: false,
    },
    Marker {
        label: "frame",
        symbol: "dual_channel::channel_loop::hand",
        whole: false,
    },
    Marker {
        label: "link message",
        symbol: "cobs_frames::Reassembler<_>::collect",
        whole: false,
    },
    Marker {
        label: "link sent",
        symbol: "dual_channel::runtime::Runtime<F,R,_,P>::send",
        whole: false,
    },
    Marker {
        label: "heartbeat",
        symbol: "dual_channel::runtime::Runtime<F,R,_,P>::heartbeat",
        whole: false,
    },
    Marker {
        label: "CAN sent",
        symbol: "board::hw::HwDriver as dual_channel::channel_loop::Driver>::transmit",
        whole: false,
    },
    Marker {
        label: "SRDO produced",
        symbol: "dual_channel::runtime::Runtime<F,R,_,P>::core_frame",
        whole: false,
    },
    Marker {
        label: "pair validated",
        symbol: "shared::safety::srdo::deliver_clamped",
        whole: false,
    },
    Marker {
        label: "verdict",
        symbol: "dual_channel::crosscheck::VerdictCheck<_,S>::arrive",
        whole: false,
    },
    Marker {
        label: "SimpleCAN packet",
        symbol: "shared::simplecan::frame::crc",
        whole: false,
    },
    Marker {
        label: "SimpleCAN sealed",
        symbol: "shared::simplecan::frame::seal",
        whole: false,
    },
    Marker {
        label: "SimpleCAN forward paired",
        symbol: "dual_channel::simplecan::ForwardCheck::pair",
        whole: false,
    },
    Marker {
        label: "SimpleCAN judged",
        symbol: "dual_channel::simplecan::transmit::TransmitCheck::judge",
        whole: false,
    },
    Marker {
        label: "USART3",
        symbol: "USART3",
        whole: true,
    },
    Marker {
        label: "CAN interrupt",
        symbol: "CAN1_",
        whole: false,
    },
    Marker {
        label: "timer",
        symbol: "TIM2",
        whole: true,
    },
];

/// The bit of marker `label` in [`Activation::marks`] (`0` when no marker has that label).
pub fn bit(label: &str) -> u32 {
    MARKERS
        .iter()
        .position(|marker| marker.label == label)
        .map_or(0, |index| 1 << index)
}

/// The safety protocol an image speaks, which decides what an activation's protocol work is
/// ([`Protocol::is_work`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// CANopen Safety: SRDOs.
    CanopenSafety,
    /// SimpleCAN: data packets and syncs.
    Simplecan,
}

impl Protocol {
    /// The markers whose entry in a loop iteration is the protocol's work. CANopen Safety: an
    /// SRDO frame handled (`hand`: in the Operational window without load, the only frames
    /// the channels' filters pass), an SRDO produced, a pair validated, the other channel's
    /// verdict taken. SimpleCAN: a packet's CRC computed (every data packet or sync of a
    /// known SC-ID decoded, every one produced, `frame::crc`), a packet sealed for the bus,
    /// channel A's forwarded copy paired (channel B), channel A's packet on the bus judged
    /// against channel B's own (channel B, Model A), the other channel's verdict taken.
    pub fn work_marks(self) -> u32 {
        match self {
            Protocol::CanopenSafety => {
                bit("frame") | bit("SRDO produced") | bit("pair validated") | bit("verdict")
            }
            Protocol::Simplecan => {
                bit("SimpleCAN packet")
                    | bit("SimpleCAN sealed")
                    | bit("SimpleCAN forward paired")
                    | bit("SimpleCAN judged")
                    | bit("verdict")
            }
        }
    }

    /// Whether `activation` ran the loop and did the protocol's work ([`Protocol::work_marks`]).
    pub fn is_work(self, activation: &Activation) -> bool {
        self.is_work_marks(activation.marks)
    }

    /// [`Protocol::is_work`] of an activation that entered the markers `marks`.
    pub fn is_work_marks(self, marks: u32) -> bool {
        marks & bit("loop") != 0 && marks & self.work_marks() != 0
    }
}

/// One activation: what ran from one wake-up to the next.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Activation {
    /// When the core woke for it (virtual time, ns).
    pub at: u64,
    /// Instructions executed.
    pub instructions: u64,
    /// The [`MARKERS`] entered, one bit each in their order.
    pub marks: u32,
    /// Times the first marker (the channel loop's iteration) was entered.
    pub iterations: u32,
}

impl Activation {
    /// Whether marker `label` was entered.
    pub fn has(&self, label: &str) -> bool {
        self.marks & bit(label) != 0
    }

    /// The labels of the markers entered, joined by `+` (`interrupts only` when the loop did
    /// not run and no marker was entered).
    pub fn describe(&self) -> String {
        let labels: Vec<&str> = MARKERS
            .iter()
            .enumerate()
            .filter(|(index, _)| self.marks & (1 << index) != 0)
            .map(|(_, marker)| marker.label)
            .collect();
        if labels.is_empty() {
            "nothing marked".to_owned()
        } else {
            labels.join("+")
        }
    }
}

/// What one block start holds: instructions counted there and the markers it is the entry of.
#[derive(Clone, Copy, Debug, Default)]
struct BlockCount {
    instructions: u64,
    marks: u32,
}

/// The profile of one machine since [`crate::cpu::Machine::start_profile`].
#[derive(Clone, Debug)]
pub struct Profile {
    blocks: HashMap<u32, BlockCount>,
    /// Function entries of the markers: address (Thumb bit clear) to marker bits.
    entries: HashMap<u32, u32>,
    current: Activation,
    /// The blocks of the current activation, in order, with their instructions.
    current_blocks: Vec<(u32, u32)>,
    /// The blocks of the last activation that was a loop iteration woken by the timer alone
    /// ([`Profile::timer_iteration`]).
    timer_iteration: Vec<(u32, u32)>,
    activations: Vec<Activation>,
    /// Instructions per block start, per set of markers an activation entered: the blocks
    /// of every ended activation, summed under its [`Activation::marks`]
    /// ([`Profile::functions_of`]).
    by_marks: HashMap<u32, HashMap<u32, u64>>,
    lowest_sp: u32,
    /// Whether blocks and activations are counted ([`Profile::pause`]); the deepest stack
    /// always is.
    counting: bool,
}

impl Profile {
    /// A profile that finds [`MARKERS`] in `symbols`.
    pub fn new(symbols: &Symbols) -> Profile {
        let mut entries: HashMap<u32, u32> = HashMap::new();
        for (index, marker) in MARKERS.iter().enumerate() {
            for start in symbols.starts_of(marker.symbol, marker.whole) {
                *entries.entry(start).or_default() |= 1 << index;
            }
        }
        Profile {
            blocks: HashMap::new(),
            entries,
            current: Activation::default(),
            current_blocks: Vec::new(),
            timer_iteration: Vec::new(),
            activations: Vec::new(),
            by_marks: HashMap::new(),
            lowest_sp: u32::MAX,
            counting: true,
        }
    }

    /// Counts a block of `instructions` starting at `address`, entered with the stack pointer
    /// at `sp`.
    pub fn block(&mut self, address: u32, instructions: u32, sp: u32) {
        self.lowest_sp = self.lowest_sp.min(sp);
        if !self.counting {
            return;
        }
        let entries = &self.entries;
        let count = self.blocks.entry(address).or_insert_with(|| BlockCount {
            instructions: 0,
            marks: entries.get(&address).copied().unwrap_or(0),
        });
        count.instructions += u64::from(instructions);
        self.current.instructions += u64::from(instructions);
        self.current.marks |= count.marks;
        self.current.iterations += count.marks & 1;
        self.current_blocks.push((address, instructions));
    }

    /// The core woke at `at` (virtual time): the activation before ends here.
    pub fn woke(&mut self, at: u64) {
        if !self.counting {
            return;
        }
        let ended = std::mem::replace(
            &mut self.current,
            Activation {
                at,
                ..Activation::default()
            },
        );
        let blocks = self.by_marks.entry(ended.marks).or_default();
        for &(address, instructions) in &self.current_blocks {
            *blocks.entry(address).or_default() += u64::from(instructions);
        }
        if ended.marks == bit("loop") | bit("timer") && ended.iterations == 1 {
            std::mem::swap(&mut self.timer_iteration, &mut self.current_blocks);
        }
        self.current_blocks.clear();
        if ended.instructions > 0 {
            self.activations.push(ended);
        }
    }

    /// The last activation that was one loop iteration woken by the timer and nothing else
    /// (the input sample's: an idle iteration), as instructions per function in the order
    /// the functions were first entered.
    pub fn timer_iteration(&self, symbols: &Symbols) -> Vec<(String, u64)> {
        let mut functions: Vec<(String, u64)> = Vec::new();
        for &(address, instructions) in &self.timer_iteration {
            let name = symbols
                .function(address)
                .map_or_else(|| format!("{address:#010x}"), short_name);
            match functions.iter_mut().find(|(known, _)| *known == name) {
                Some((_, sum)) => *sum += u64::from(instructions),
                None => functions.push((name, u64::from(instructions))),
            }
        }
        functions
    }

    /// The activations ended so far, oldest first.
    pub fn activations(&self) -> &[Activation] {
        &self.activations
    }

    /// The lowest stack pointer seen at a block's start (`u32::MAX`: no block yet).
    pub fn lowest_sp(&self) -> u32 {
        self.lowest_sp
    }

    /// Instructions per function (by `symbols`; blocks outside every symbol under their
    /// address), most first.
    pub fn functions(&self, symbols: &Symbols) -> Vec<(String, u64)> {
        by_function(symbols, self.blocks())
    }

    /// Instructions per function of the ended activations whose markers `which` accepts (by
    /// `symbols`, as [`Profile::functions`]), most first: where the instructions of one kind
    /// of activation go (a pair's work: [`Protocol::is_work`]).
    pub fn functions_of(
        &self,
        symbols: &Symbols,
        which: impl Fn(u32) -> bool,
    ) -> Vec<(String, u64)> {
        by_function(symbols, self.blocks_of(which))
    }

    /// Instructions per block start address of the ended activations whose markers `which`
    /// accepts, most first ([`Profile::blocks`] of one kind of activation).
    pub fn blocks_of(&self, which: impl Fn(u32) -> bool) -> Vec<(u32, u64)> {
        let mut sums: HashMap<u32, u64> = HashMap::new();
        for (_, blocks) in self.by_marks.iter().filter(|(marks, _)| which(**marks)) {
            for (&address, &instructions) in blocks {
                *sums.entry(address).or_default() += instructions;
            }
        }
        most_first(sums)
    }

    /// Instructions per block start address, most first (for a finer look than
    /// [`Profile::functions`]: `llvm-addr2line` names the source lines).
    pub fn blocks(&self) -> Vec<(u32, u64)> {
        most_first(
            self.blocks
                .iter()
                .map(|(&address, count)| (address, count.instructions)),
        )
    }

    /// Stops counting blocks and activations (what was counted stays readable); the deepest
    /// stack is still followed. [`Profile::restart`] counts again.
    pub fn pause(&mut self) {
        self.counting = false;
    }

    /// Forgets the blocks and activations counted so far (the deepest stack is kept) and
    /// counts again: the start of a new window.
    pub fn restart(&mut self) {
        self.counting = true;
        self.blocks.clear();
        self.activations.clear();
        self.by_marks.clear();
        self.current = Activation::default();
        self.current_blocks.clear();
        self.timer_iteration.clear();
    }
}

/// Instructions per function of `blocks` (instructions per block start address), by
/// `symbols` (a block outside every symbol under its address), most first.
fn by_function(symbols: &Symbols, blocks: Vec<(u32, u64)>) -> Vec<(String, u64)> {
    let mut sums: HashMap<String, u64> = HashMap::new();
    for (address, instructions) in blocks {
        let name = symbols
            .function(address)
            .map_or_else(|| format!("{address:#010x}"), short_name);
        *sums.entry(name).or_default() += instructions;
    }
    most_first(sums)
}

/// `counts` as a list, the most instructions first, equal counts in the order of their keys.
fn most_first<K: Ord>(counts: impl IntoIterator<Item = (K, u64)>) -> Vec<(K, u64)> {
    let mut list: Vec<(K, u64)> = counts.into_iter().collect();
    list.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    list
}

/// A function's name without its generic parameters (`Runtime<F,R,_,P>::send` is
/// `Runtime::send`), short enough for a table; a qualified path's angle brackets
/// (`<HwDriver as Driver>::transmit`) stay.
fn short_name(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    // Per open bracket: whether it opens generic parameters (left out).
    let mut open: Vec<bool> = Vec::new();
    let mut previous = ' ';
    for c in name.chars() {
        let hidden = open.iter().any(|&generic| generic);
        match c {
            '<' => {
                let generic = previous.is_alphanumeric() || previous == '_';
                if !hidden && !generic {
                    out.push(c);
                }
                open.push(generic);
            }
            '>' => {
                let generic = open.pop().unwrap_or(true);
                let shown = !generic && !open.iter().any(|&generic| generic);
                if shown {
                    out.push(c);
                }
            }
            _ if !hidden => out.push(c),
            _ => {}
        }
        previous = c;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A kind of activation's functions count only the activations of that kind: an idle
    /// iteration's loop instructions are not a pair's, and a pair's interrupt-only wake-ups
    /// (a link byte) are not in it either.
    #[test]
    fn the_functions_of_a_kind_of_activation_count_only_that_kind() {
        let symbols = Symbols::from_functions(&[
            (
                0x100,
                0x40,
                "dual_channel::channel_loop::ChannelLoop::service",
            ),
            (0x200, 0x40, "shared::safety::srdo::deliver_clamped"),
            (0x300, 0x40, "USART3"),
        ]);
        let mut profile = Profile::new(&symbols);
        // An idle iteration, a byte, then two iterations with a validated pair.
        profile.block(0x100, 7, 0x2000_0F00);
        profile.woke(1_000);
        profile.block(0x300, 5, 0x2000_0F00);
        profile.woke(2_000);
        for at in [3_000, 4_000] {
            profile.block(0x100, 10, 0x2000_0F00);
            profile.block(0x200, 20, 0x2000_0E00);
            profile.woke(at);
        }
        let work = profile.functions_of(&symbols, |marks| {
            Protocol::CanopenSafety.is_work_marks(marks)
        });
        assert_eq!(
            work,
            [
                ("shared::safety::srdo::deliver_clamped".to_owned(), 40),
                (
                    "dual_channel::channel_loop::ChannelLoop::service".to_owned(),
                    20
                ),
            ]
        );
        let idle = profile.functions_of(&symbols, |marks| marks == bit("loop"));
        assert_eq!(
            idle,
            [(
                "dual_channel::channel_loop::ChannelLoop::service".to_owned(),
                7
            )]
        );
        assert_eq!(
            profile.blocks_of(|marks| Protocol::CanopenSafety.is_work_marks(marks)),
            [(0x200, 40), (0x100, 20)]
        );
        profile.restart();
        assert!(profile.functions_of(&symbols, |_| true).is_empty());
    }

    #[test]
    fn an_activation_sums_its_blocks_and_keeps_the_markers_entered() {
        let symbols = Symbols::from_functions(&[
            (
                0x100,
                0x40,
                "dual_channel::channel_loop::ChannelLoop::service",
            ),
            (0x200, 0x40, "USART3"),
        ]);
        let mut profile = Profile::new(&symbols);
        profile.block(0x200, 5, 0x2000_1000);
        profile.woke(1_000);
        profile.block(0x100, 10, 0x2000_0F00);
        profile.block(0x110, 3, 0x2000_0F00);
        profile.woke(2_000);
        let [byte, iteration] = profile.activations() else {
            panic!("two activations: {:?}", profile.activations());
        };
        assert_eq!((byte.instructions, byte.describe().as_str()), (5, "USART3"));
        assert_eq!((iteration.at, iteration.instructions), (1_000, 13));
        assert!(iteration.has("loop") && !iteration.has("USART3"));
        assert_eq!(profile.lowest_sp(), 0x2000_0F00);
        let functions = profile.functions(&symbols);
        assert_eq!(
            functions[0],
            (
                "dual_channel::channel_loop::ChannelLoop::service".to_owned(),
                13
            )
        );
    }

    /// The SimpleCAN markers are found in an image's symbols, and an activation that entered
    /// one of them in a loop iteration is SimpleCAN's work, not CANopen Safety's; without the
    /// loop it is neither.
    #[test]
    fn a_packets_crc_in_a_loop_iteration_is_simplecans_work() {
        let symbols = Symbols::from_functions(&[
            (
                0x100,
                0x40,
                "dual_channel::channel_loop::ChannelLoop::service",
            ),
            (0x200, 0x40, "shared::simplecan::frame::crc"),
        ]);
        let mut profile = Profile::new(&symbols);
        profile.block(0x100, 10, 0x2000_1000);
        profile.block(0x200, 20, 0x2000_0F00);
        profile.woke(1_000);
        profile.block(0x200, 20, 0x2000_0F00);
        profile.woke(2_000);
        let [iteration, alone] = profile.activations() else {
            panic!("two activations: {:?}", profile.activations());
        };
        assert!(
            iteration.has("SimpleCAN packet"),
            "{}",
            iteration.describe()
        );
        assert!(Protocol::Simplecan.is_work(iteration));
        assert!(!Protocol::CanopenSafety.is_work(iteration));
        assert!(!Protocol::Simplecan.is_work(alone));
    }

    #[test]
    fn a_paused_profile_counts_nothing_but_still_follows_the_stack() {
        let symbols = Symbols::from_functions(&[(0x100, 0x40, "USART3")]);
        let mut profile = Profile::new(&symbols);
        profile.pause();
        profile.block(0x100, 5, 0x2000_0800);
        profile.woke(1_000);
        assert!(profile.activations().is_empty() && profile.blocks().is_empty());
        assert_eq!(profile.lowest_sp(), 0x2000_0800);
        profile.restart();
        profile.block(0x100, 5, 0x2000_1000);
        profile.woke(2_000);
        assert_eq!(profile.activations().len(), 1);
        assert_eq!(profile.lowest_sp(), 0x2000_0800);
    }

    #[test]
    fn generic_parameters_are_left_out_of_a_function_name() {
        assert_eq!(
            short_name("dual_channel::runtime::Runtime<F,R,_,P>::send"),
            "dual_channel::runtime::Runtime::send"
        );
        assert_eq!(
            short_name("<board::hw::HwDriver as dual_channel::channel_loop::Driver>::transmit"),
            "<board::hw::HwDriver as dual_channel::channel_loop::Driver>::transmit"
        );
        assert_eq!(
            short_name("<embassy_time::Timer as core::future::Future>::poll"),
            "<embassy_time::Timer as core::future::Future>::poll"
        );
        assert_eq!(
            short_name("embassy_executor::raw::TaskStorage<F>::poll"),
            "embassy_executor::raw::TaskStorage::poll"
        );
    }
}
