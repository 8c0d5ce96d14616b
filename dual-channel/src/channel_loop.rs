//! The channel loop, written once for every board: what a channel does each time it wakes,
//! over a small driver interface ([`Driver`], in the style of canadensis' CAN driver traits).
//!
//! A board layer implements [`Driver`] (the CAN controller's transmit and receive queues and
//! acceptance filters, the link to the other channel, the input and output pins, the clock)
//! and calls [`ChannelLoop::service`] whenever something arrived or the returned instant has
//! come; waiting is the board's business (an async select on hardware), the
//! rest is here, sans-I/O and host-tested:
//!
//! - **Acceptance filters**: derived from the configuration ([`crate::filters`]) and handed to
//!   the driver whenever they change; every received frame is also judged by the same list in
//!   software, so a board whose controller passes more (the bank fallback passes the SRDO
//!   range) sees exactly the same frames.
//! - **Receive**: the driver's queue, frame by frame; a queue overrun of frames the filters
//!   passed is the safe state with its own cause ([`Received::Overrun`]), never a silent loss.
//! - **Inputs, one policy for every board**: each input pin is read on every wake-up and at
//!   least every [`SAMPLE_PERIOD`]; the first sample and every change go to the runtime, a
//!   sample equal to the last does not, but the runtime learns that the pins were read
//!   ([`Runtime::inputs_sampled`]): channel B co-signs only a value read within the sample
//!   window, counted from the reading. Sampling on a period bounds the input latency on a
//!   board whose pins raise no event (GPIO without EXTI, as here); handing on changes only
//!   keeps the link from carrying a digest per millisecond (each sample the runtime takes is
//!   one `Inputs` message to the other channel). The emulated board's pin changes only when
//!   the hub says so: the same rule gives it the same behaviour.
//! - **Outputs**: each output pin follows the received object the device description names
//!   for it ([`safety_device::OUTPUT_PINS`]), read from the confirmed data of the receive
//!   SRDO that maps it, or (feature `simplecan`) from the confirmed value of the consumed
//!   SimpleCAN SC-ID whose SDD entry maps it; low when none does and in the safe state.
//! - **SimpleCAN's transmissions** (feature `simplecan`, a runtime whose protocol
//!   ([`ChannelProtocol`]) has SimpleCAN beside the SRDOs): the frames the controller
//!   confirmed as sent ([`Driver::transmitted`]) go to the runtime
//!   ([`Runtime::on_transmitted`]: SC_REQ_18, SC_REQ_23), and the frames the core withdraws
//!   go to the controller ([`Driver::abort`]).

use crate::filters::AcceptanceList;
use crate::runtime::{ChannelEvent, ChannelProtocol, Io, Role, Runtime};
use shared::canopen::lss::{BitRate, LssEvent};
use shared::canopen::nmt::NmtState;
use shared::canopen::od::Address;
use shared::canopen::storage::Flash;
use shared::node::Event;
use shared::safety::config::SrdoRecord;
use shared::safety::types::{Direction, SrdoNumber};
use shared::{CanFrame, Instant};

/// Reads that drop what the link buffered while the processor was held
/// ([`Driver::link_deaf`]): more than its receive buffer holds in reads of 64 bytes, so the
/// drop ends however the board buffers, while bytes keep coming.
const LINK_DRAIN_READS: usize = 16;
/// Input pins are read at least this often: the device's input sample period.
pub use safety_device::timing::INPUT_SAMPLE_PERIOD as SAMPLE_PERIOD;

/// Frames taken from the receive queue in one [`ChannelLoop::service`], so that a queue kept
/// full cannot hold the loop (and the watchdog it feeds) for ever: the loop asks to be called
/// again at once instead.
pub const RECEIVE_BUDGET: usize = 32;

/// The most input pins or output pins a channel drives.
pub const MAX_PINS: usize = 8;

/// A transmit queue (CAN or link) had no room: the frame or bytes were not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct QueueFull;

/// What the receive queue hands out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Received {
    /// A frame, oldest first.
    Frame(CanFrame),
    /// Frames were lost since the last call because the queue was full.
    Overrun,
    /// The CAN controller went bus-off since the last call: frames may have gone unseen
    /// while it neither sent nor received.
    BusOff,
}

/// A board as the channel loop sees it.
pub trait Driver {
    /// The time now (microseconds since power-on; never goes backwards).
    fn now(&mut self) -> Instant;
    /// Queues `frame` for the bus. Frames leave by identifier, lowest first (as bxCAN's
    /// mailboxes and CAN arbitration have it), in queue order within one identifier.
    fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull>;
    /// The oldest received frame, `None` when the queue is empty.
    fn receive(&mut self) -> Option<Received>;
    /// Programs the controller's acceptance filters to pass (at least) `list`, and from now
    /// on nothing outside the SRDO range that is not in it.
    fn apply_filters(&mut self, list: &AcceptanceList);
    /// Queues `bytes` for the link to the other channel, all or nothing.
    fn link_write(&mut self, bytes: &[u8]) -> Result<(), QueueFull>;
    /// Link bytes received, into `buf`; how many (0: none).
    fn link_read(&mut self, buf: &mut [u8]) -> usize;
    /// The level of input pin `pin` (`true`: closed).
    fn input(&mut self, pin: usize) -> bool;
    /// Drives output pin `pin` (`true`: energised).
    fn set_output(&mut self, pin: usize, level: bool);
    /// Reports `event` (log, diagnostics).
    fn event(&mut self, event: &ChannelEvent);
    /// Switches the CAN controller to `rate` now: LSS activate bit timing, after its first
    /// switch delay, while the node is silent (CiA 305 Fig. 35; `shared::canopen::lss`, rule
    /// 4). Called only with a rate of the set the board enabled LSS with
    /// ([`Runtime::enable_lss`]). The default switches nothing: a board that enables only the
    /// rate it runs at is never asked for another.
    fn switch_bit_rate(&mut self, rate: BitRate) {
        let _ = rate;
    }
    /// `true`, once, when the processor could not receive link bytes for a while since the
    /// last call (a flash program held it: a store of the parameters); the loop then tells
    /// the runtime ([`Runtime::link_was_deaf`]). The default: never (a board whose link
    /// receives whatever the processor does, or whose flash does not stall it).
    fn link_deaf(&mut self) -> bool {
        false
    }
    /// Whether the runtime restarted its link receiver after [`Driver::link_deaf`] (`false`:
    /// in Operational, where it judges what it finds), for the board's log.
    fn link_restarted(&mut self, restarted: bool) {
        let _ = restarted;
    }
    /// The oldest frame the controller put on the bus since the last call (a transmit
    /// mailbox completed), `None` when there is none (SimpleCAN's producers and master must
    /// know: SC_REQ_18, SC_REQ_23). The default reports none: a board whose controller
    /// confirms nothing, whose SimpleCAN packets are then withdrawn at the end of their slot.
    #[cfg(feature = "simplecan")]
    fn transmitted(&mut self) -> Option<CanFrame> {
        None
    }
    /// Withdraws the frames on `id` queued by [`Driver::transmit`] and not yet on the bus (a
    /// SimpleCAN packet at the end of its slot, a sync not confirmed within 2 ms: SC_REQ_18,
    /// SC_REQ_23). The default withdraws nothing: a board whose frames are on the bus as soon
    /// as they are queued.
    #[cfg(feature = "simplecan")]
    fn abort(&mut self, id: shared::CanId) {
        let _ = id;
    }
}

/// Frames and bytes the driver's queues had no room for, since power-on (saturating).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Dropped {
    /// CAN frames the transmit queue refused: the consumers' SRVT and channel A's transmit
    /// check catch a lost SRDO frame.
    pub frames: u32,
    /// Link messages the link queue refused: the other channel sees the sequence gap (the
    /// safe state in both channels).
    pub link_messages: u32,
}

/// The runtime's I/O, on the driver.
struct DriverIo<'a, D: Driver> {
    driver: &'a mut D,
    outputs_changed: bool,
    dropped: &'a mut Dropped,
}

impl<D: Driver> Io for DriverIo<'_, D> {
    fn transmit(&mut self, frame: CanFrame) {
        if self.driver.transmit(&frame).is_err() {
            self.dropped.frames = self.dropped.frames.saturating_add(1);
        }
    }
    fn link(&mut self, bytes: &[u8]) {
        if self.driver.link_write(bytes).is_err() {
            self.dropped.link_messages = self.dropped.link_messages.saturating_add(1);
        }
    }
    fn output(&mut self, _: SrdoNumber, _: u64) {
        self.outputs_changed = true;
    }
    fn event(&mut self, event: ChannelEvent) {
        self.driver.event(&event);
        if let ChannelEvent::Node(Event::Lss(LssEvent::SwitchBitRate(rate))) = event {
            self.driver.switch_bit_rate(rate);
        }
    }
    #[cfg(feature = "simplecan")]
    fn simplecan_output(&mut self, _: u8, _: u32) {
        self.outputs_changed = true;
    }
    #[cfg(feature = "simplecan")]
    fn abort(&mut self, id: shared::CanId) {
        self.driver.abort(id);
    }
}

/// The pins of a device: which objects each input pin is sampled into, which object drives
/// each output pin ([`safety_device::INPUT_PINS`], [`safety_device::OUTPUT_PINS`]).
#[derive(Clone, Copy, Debug)]
pub struct Pins {
    /// Per input pin, its plain object and the inverted copy.
    pub inputs: &'static [(Address, Address)],
    /// Per output pin, the received object that drives it.
    pub outputs: &'static [Address],
}

/// One channel's loop around its runtime: the filters it applied, its pins' last values. The
/// runtime stays the board's ([`ChannelLoop::service`] borrows it): built where the board
/// keeps it, it is not moved again (moved into the loop, it went through the stack once more,
/// deeper than the stack reserve: `docs/footprint.md`).
#[derive(Clone)]
pub struct ChannelLoop {
    pins: Pins,
    /// The acceptance list last handed to the driver (`None`: none yet).
    filters: Option<AcceptanceList>,
    /// The list was built in the current Operational period: it stands until the node
    /// leaves Operational.
    filters_in_operational: bool,
    /// The last sample handed to the runtime per input pin.
    sampled: [Option<bool>; MAX_PINS],
    next_sample: Instant,
    /// The level last driven per output pin (`None`: not driven yet).
    levels: [Option<bool>; MAX_PINS],
    /// The output pins were driven once (all low before the first confirmed pair).
    driven: bool,
    /// When the runtime wants to be polled.
    runtime_deadline: Instant,
    dropped: Dropped,
    /// Where link bytes are read into: kept from one iteration to the next, so that no
    /// iteration clears a buffer first (the bytes read are the only ones used).
    link: [u8; 64],
}

impl ChannelLoop {
    /// The loop for a device with these `pins` (at most [`MAX_PINS`] of each; more are never
    /// read or driven).
    pub fn new(pins: Pins) -> Self {
        ChannelLoop {
            pins,
            filters: None,
            filters_in_operational: false,
            sampled: [None; MAX_PINS],
            next_sample: Instant::ZERO,
            levels: [None; MAX_PINS],
            driven: false,
            runtime_deadline: Instant::ZERO,
            dropped: Dropped::default(),
            link: [0; 64],
        }
    }

    /// What the driver's transmit queues refused so far.
    pub fn dropped(&self) -> Dropped {
        self.dropped
    }

    /// The acceptance list the driver was last given.
    pub fn filters(&self) -> Option<&AcceptanceList> {
        self.filters.as_ref()
    }

    /// Handles what arrived (at most [`RECEIVE_BUDGET`] frames, the link bytes, the input
    /// pins), runs what is due and drives the outputs; returns when to call again at the
    /// latest (`now` itself when frames were left in the queue).
    #[must_use = "the loop must be called again at the returned instant"]
    #[inline(never)]
    pub fn service<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>>(
        &mut self,
        runtime: &mut Runtime<F, R, N, P>,
        driver: &mut impl Driver,
    ) -> Instant {
        let mut io = DriverIo {
            driver,
            outputs_changed: false,
            dropped: &mut self.dropped,
        };
        let mut handed = false;
        let mut taken = 0;
        while taken < RECEIVE_BUDGET {
            let Some(received) = io.driver.receive() else {
                break;
            };
            taken += 1;
            handed |= hand(runtime, received, &self.filters, &mut io);
        }
        // The budget used up: the queue may hold more; the board calls again at once.
        let mut more = taken == RECEIVE_BUDGET;
        // A store above may have held the processor while link bytes came: before reading
        // them, the runtime learns that some may be lost.
        if io.driver.link_deaf() {
            let at = io.driver.now();
            let restarted = runtime.link_was_deaf(at);
            if restarted {
                // What came while the processor was held may miss bytes anywhere, after a
                // valid frame as much as before one: all of it is dropped, and the receiver
                // starts on what comes from now on (a frame cut by the drop is a remnant).
                let mut dropped = [0u8; 64];
                for _ in 0..LINK_DRAIN_READS {
                    if io.driver.link_read(&mut dropped) == 0 {
                        break;
                    }
                }
            }
            io.driver.link_restarted(restarted);
        }
        let count = io.driver.link_read(&mut self.link);
        if let Some(bytes) = self.link.get(..count).filter(|bytes| !bytes.is_empty()) {
            let at = io.driver.now();
            runtime.on_link_bytes(at, bytes, &mut io);
            handed = true;
            // The link may have more than one buffer's worth: come back at once.
            more |= count == self.link.len();
        }
        // The pins are read on every wake-up; the period only bounds the gap between two.
        let now = io.driver.now();
        for (pin, &(plain, inverted)) in self.pins.inputs.iter().enumerate().take(MAX_PINS) {
            let level = io.driver.input(pin);
            if self.sampled[pin] != Some(level) {
                self.sampled[pin] = Some(level);
                // The objects are the device description's own: a refusal is a description
                // error, which the runtime reports as an input table fault where it can.
                let _ = runtime.set_input(now, plain, inverted, &[u8::from(level)], &mut io);
                handed = true;
            }
        }
        // Every pin was read now, changed or not: the samples' age counts from here.
        runtime.inputs_sampled(now, &mut io);
        self.next_sample = now + SAMPLE_PERIOD;
        if handed || shared::time::expired(self.runtime_deadline, now) {
            self.runtime_deadline = runtime.poll(now, &mut io);
            // In Operational the configuration cannot change (EN 50325-5 8.2.2: the SRDO
            // objects refuse writes there), so the list built on entering it stands; outside
            // it an SDO write may change it at any iteration.
            let operational = runtime.node().nmt_state() == NmtState::Operational;
            if !(operational && self.filters_in_operational) {
                #[cfg_attr(
                    not(feature = "simplecan"),
                    expect(unused_mut, reason = "only SimpleCAN adds to the list")
                )]
                let mut list =
                    AcceptanceList::of(runtime.node().node_id(), runtime.node().safety_config());
                #[cfg(feature = "simplecan")]
                if let Some(layer) = runtime.node().protocol().simplecan() {
                    list.add_simplecan(&layer);
                }
                if self.filters.as_ref() != Some(&list) {
                    io.driver.apply_filters(&list);
                    self.filters = Some(list);
                }
            }
            self.filters_in_operational = operational;
        }
        // SimpleCAN's producers and master learn what went out (what the calls above sent,
        // on a board whose controller confirms at once, and what completed since the last
        // call); what the confirmations make due runs at once.
        #[cfg(feature = "simplecan")]
        {
            let mut confirmed = false;
            while let Some(frame) = io.driver.transmitted() {
                let at = io.driver.now();
                runtime.on_transmitted(at, &frame, &mut io);
                confirmed = true;
            }
            if confirmed {
                self.runtime_deadline = runtime.poll(now, &mut io);
            }
        }
        if io.outputs_changed || !self.driven {
            self.driven = true;
            for (pin, &object) in self.pins.outputs.iter().enumerate().take(MAX_PINS) {
                let level = output_level(runtime, object);
                if self.levels[pin] != Some(level) {
                    self.levels[pin] = Some(level);
                    io.driver.set_output(pin, level);
                }
            }
        }
        if more {
            now
        } else {
            self.runtime_deadline.min(self.next_sample)
        }
    }
}

/// Hands one received item to the runtime; `true` when the runtime saw it.
#[inline(never)]
fn hand<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>, D: Driver>(
    runtime: &mut Runtime<F, R, N, P>,
    received: Received,
    filters: &Option<AcceptanceList>,
    io: &mut DriverIo<'_, D>,
) -> bool {
    match received {
        Received::Frame(frame) => {
            // Before the first filters are applied the runtime has not booted (it has not
            // been polled), and it ignores every frame; after, only what the list passes.
            if filters.as_ref().is_some_and(|list| list.accepts(&frame)) {
                let at = io.driver.now();
                runtime.on_frame(at, &frame, io);
                true
            } else {
                false
            }
        }
        Received::Overrun => {
            runtime.on_receive_overrun(io);
            true
        }
        Received::BusOff => {
            runtime.on_bus_off(io);
            true
        }
    }
}

/// The level of the output pin driven by `object`: the object's value in the confirmed
/// data of a receive SRDO that maps it is not 0, or (feature `simplecan`) the confirmed value
/// of a consumed SimpleCAN SC-ID whose SDD entry maps it is not 0.
#[inline(never)]
fn output_level<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>>(
    runtime: &Runtime<F, R, N, P>,
    object: Address,
) -> bool {
    #[cfg(feature = "simplecan")]
    if simplecan_level(runtime, object) {
        return true;
    }
    runtime
        .node()
        .safety_config()
        .srdos
        .iter()
        .enumerate()
        .filter(|(_, record)| record.parsed_direction() == Ok(Direction::Receive))
        .filter_map(|(index, record)| {
            let srdo = SrdoNumber::of_slot(index)?;
            mapped_value(record, object, runtime.output(srdo))
        })
        .any(|value| value != 0)
}

/// `true` when a consumed SimpleCAN SC-ID whose SDD entry maps `object` (5E10h.. :06) has a
/// confirmed value that is not 0 (`Runtime::simplecan_output`: 0 in the safe state).
#[cfg(feature = "simplecan")]
fn simplecan_level<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>>(
    runtime: &Runtime<F, R, N, P>,
    object: Address,
) -> bool {
    let Some(layer) = runtime.node().protocol().simplecan() else {
        return false;
    };
    layer.entries[..layer.count.min(layer.entries.len())]
        .iter()
        .filter(|entry| entry.role == shared::node::simplecan::ROLE_CONSUME)
        .filter(|entry| mapped_object(entry.mapped) == object)
        .any(|entry| runtime.simplecan_output(entry.sc_id) != 0)
}

/// The object of a mapping entry `index << 16 | sub-index << 8 | bits` (EN 50325-5 6.4.1.3,
/// and SimpleCAN's 5E10h.. :06 alike).
fn mapped_object(entry: u32) -> Address {
    Address::new((entry >> 16) as u16, (entry >> 8) as u8)
}

/// The value of `object` in an SRDO's plain data `data` (little-endian, as the frame carries
/// it), when the record maps it as plain data: the plain entries are the odd sub-indices
/// (entries 0, 2, 4, ...), each in the frame right after the one before (EN 50325-5
/// 6.4.1.3). `None` when the record does not map it.
pub fn mapped_value(record: &SrdoRecord, object: Address, data: u64) -> Option<u64> {
    let mut offset = 0u32;
    // The plain entries: 0, 2, 4, ...; each is followed by its inverted copy.
    for pair in record.entries().chunks(2) {
        let entry = pair[0];
        let bits = entry & 0xFF;
        if bits == 0 || bits % 8 != 0 || offset + bits > 64 {
            return None; // Not a mapping the validation accepts: drives nothing.
        }
        if mapped_object(entry) == object {
            let value = data >> offset;
            return Some(if bits == 64 {
                value
            } else {
                value & ((1 << bits) - 1)
            });
        }
        offset += bits;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(entries: &[u32]) -> SrdoRecord {
        let mut record = SrdoRecord::DELETED;
        record.direction = 2;
        record.mapping_count = entries.len() as u8;
        record.mapping[..entries.len()].copy_from_slice(entries);
        record
    }

    /// EN 50325-5 6.4.1.3, 6.4.1.4: the plain objects follow each other in the plain frame; an output
    /// pin reads its object at its place, whatever else the SRDO maps, and nothing from an
    /// SRDO that does not map it or maps it only as an inverted copy.
    #[test]
    fn en50325_5_6_4_1_4_an_output_pin_reads_its_object_at_its_place_in_the_frame() {
        let output = Address::new(0x6200, 1);
        let alone = record(&[0x6200_0108, 0x6201_0108]);
        assert_eq!(mapped_value(&alone, output, 0x01), Some(1));
        assert_eq!(mapped_value(&alone, output, 0xFF00), Some(0));
        // Behind a 16-bit object: byte 2.
        let behind = record(&[0x6210_0110, 0x6211_0110, 0x6200_0108, 0x6201_0108]);
        assert_eq!(mapped_value(&behind, output, 0x00_FFFF), Some(0));
        assert_eq!(mapped_value(&behind, output, 0x01_0000), Some(1));
        // Mapped only as the inverted copy, or not at all: drives nothing.
        let inverted_only = record(&[0x6210_0108, 0x6200_0108]);
        assert_eq!(mapped_value(&inverted_only, output, u64::MAX), None);
        assert_eq!(mapped_value(&record(&[]), output, u64::MAX), None);
        // A mapping no validation accepts (no length, beyond 8 bytes) drives nothing.
        assert_eq!(mapped_value(&record(&[0x6200_0100, 0]), output, 1), None);
        let long = record(&[0x6300_0140, 0x6301_0140, 0x6200_0108, 0x6201_0108]);
        assert_eq!(mapped_value(&long, output, u64::MAX), None);
    }
}
