//! Emulated MCUs on one CAN bus in one process, in one deterministic virtual time: each
//! MCU's bxCAN on the bus model the host simulation and the hub use ([`can_hub::bus`]:
//! arbitration by identifier, bit time with stuff bits, the hub's fault vocabulary), the two
//! channels of a node with their USART3s crossed (the link), inputs driven and outputs
//! observed.
//!
//! # Time
//! The MCUs run in lockstep rounds of at most one [`Network::quantum`] of virtual time; no
//! MCU is ever more than a round ahead of another. Nothing one MCU does reaches another
//! sooner than a round: a link word arrives a whole word time after it starts (one word at
//! the link's 1 Mbit/s is the default round), a CAN frame no sooner than the shortest frame
//! after its arbitration. So every word and every frame reaches its receivers at the instant
//! the models compute, never after they have run past it. A transmit request ends its MCU's
//! round at once ([`Machine::yield_on_transmit_request`]) so that arbitration on an idle bus
//! starts at the instant of the request; what the model does not resolve is the order of two
//! requests within one round on an idle bus: they arbitrate together, by identifier, as if
//! made at the first one's instant.
//!
//! # Bit rate
//! The bus runs at one bit rate. A controller whose bit time (RM0090 32.7.7, from its BTR and
//! PCLK1) differs from the bus's by more than the oscillator tolerance CAN allows
//! ([`BIT_RATE_TOLERANCE`]) is out of step: it receives no frame (each counts as a receive
//! error, RM0090 32.7.6), and a frame it sends is acknowledged by nobody (a transmit error
//! each time) and never reaches the bus. The error flags such a controller drives on a real
//! bus, which destroy the others' frames until it is error passive, are not modelled.
//! The bus changes its rate as an LSS master makes every device on it change (CiA 305
//! Fig. 34 and 35): the master's configure bit timing names the rate, its activate bit timing
//! switches the master and every participant that is not an emulated MCU (the tools) to it
//! after the switch delay; an emulated MCU follows only if its own firmware reprograms its
//! controller. An activate bit timing after a rate the table does not name, or with none
//! configured, changes nothing.
//!
//! # Determinism
//! The MCUs run in a fixed order, the bus is the hub's deterministic model, every event is
//! ordered by time and then by MCU: the same images, inputs and faults give the same trace.

use can_hub::bus::{Bus, Delivery};
use shared::{CanFrame, CanId, Instant};

use crate::cpu::{Config, EngineError, Machine};
use crate::image::Image;
use crate::observed::LinkGaps;
use crate::peripherals::bxcan::{BusError, Frame, Identifier};
use crate::peripherals::gpio::Port;
use crate::peripherals::rcc::Hse;
use crate::stop::{Outcome, Stop};
use crate::time::Nanos;

/// One round of the lockstep, by default: one word on the link at 1 Mbit/s (10 bit times).
pub const DEFAULT_QUANTUM: Nanos = 10_000;

/// How far a controller's bit time may be from the bus's and still take part: the oscillator
/// tolerance of ISO 11898-1 (1.58 %), in parts per ten thousand.
pub const BIT_RATE_TOLERANCE: u64 = 158;

/// The bits over which a controller's bit time is compared with the bus's.
const STEP_BITS: u64 = 10_000;

/// `true` when a controller whose `bits` bits last `duration` keeps step with a bus at
/// `bit_rate` ([`BIT_RATE_TOLERANCE`]).
fn in_step(duration: Nanos, bits: u64, bit_rate: u32) -> bool {
    let bus = bits * 1_000_000_000 / u64::from(bit_rate.max(1));
    duration.abs_diff(bus) * 10_000 <= bus * BIT_RATE_TOLERANCE
}

/// The node-ID switches: PC2 (bit 0) to PC8 (bit 6), closed = driven high (`board::hw`).
const NODE_ID_PINS: usize = 2;
/// The channel's safety input contact, closed = high (`board::hw`).
const INPUT_PIN: usize = 0;
/// The channel's safety output, 1 = the relay enabled (`board::hw`).
const OUTPUT_PIN: usize = 1;

/// One MCU of the network, before it starts.
pub struct Member {
    /// Its name in traces and reports (`node1a`).
    pub name: String,
    /// The sealed image it runs.
    pub image: Image,
    /// The node-ID its switches are set to (`None`: all open).
    pub node_id: Option<u8>,
    /// Whether its safety input contact is closed at power-on.
    pub input_closed: bool,
    /// Its crystal.
    pub hse: Hse,
}

/// What happened in the network, in time order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// A frame ended on the bus (its sender named; external participants by their
    /// participant number).
    Frame {
        /// When its last bit ended, as the receivers got it.
        at: Nanos,
        /// The sender's name.
        from: String,
        /// The frame as the receivers got it.
        frame: CanFrame,
    },
    /// An MCU's safety output changed.
    Output {
        /// When the network saw it (the end of the round it changed in).
        at: Nanos,
        /// The MCU.
        mcu: usize,
        /// The relay enabled.
        on: bool,
    },
    /// An MCU was reset (its watchdog ran out, or its software asked for it) and starts
    /// again from its image, as a board does.
    Reset {
        /// The MCU.
        mcu: usize,
        /// Why, with the code that ran.
        stop: Stop,
        /// When.
        at: Nanos,
    },
    /// An MCU stopped: a fault, a lockup, an unclaimed access, or a reset it could not start
    /// again from (no vector table). It runs no further.
    Stopped {
        /// The MCU.
        mcu: usize,
        /// Why.
        stop: Stop,
        /// When.
        at: Nanos,
    },
    /// The bus changed its bit rate: the LSS master's activate bit timing (CiA 305 Fig. 35)
    /// took effect for the master and every participant that is not an emulated MCU
    /// ([`Network`]'s bit-rate model).
    BitRate {
        /// When: the switch delay after the request ended on the bus.
        at: Nanos,
        /// The new bit rate.
        bit_rate: u32,
    },
    /// An MCU's CAN controller put a frame on the bus that the bus model cannot carry (an
    /// extended identifier): the bus carries only CAN 2.0A frames. The frame is ended with
    /// a form error on the sender's side.
    Refused {
        /// The MCU.
        mcu: usize,
        /// When.
        at: Nanos,
        /// The frame.
        frame: Frame,
    },
}

/// Why the network could not be built.
#[derive(Debug, thiserror::Error)]
pub enum NetworkError {
    /// Unicorn could not be set up for an MCU.
    #[error("{name}: {error}")]
    Engine {
        /// The MCU.
        name: String,
        /// What failed.
        error: EngineError,
    },
    /// An MCU could not be reset into its image (no vector table, for one).
    #[error("{name}: {stop}")]
    Reset {
        /// The MCU.
        name: String,
        /// Why.
        stop: Stop,
    },
}

/// An emulated MCU in the network.
struct Mcu {
    name: String,
    machine: Machine,
    /// The MCU whose USART3 RX its USART3 TX drives, while the link is not cut.
    peer: Option<usize>,
    link_cut: bool,
    /// Transmissions still to be destroyed by a bit error ([`Network::inject_bit_errors`]).
    bit_errors: u32,
    stopped: bool,
    output: bool,
    /// When its current offer was first seen by the bus (a transmit request in this round,
    /// or an older offer waiting since the start of the round).
    offering_since: Option<Nanos>,
    /// The end of its frame on the bus, while it is transmitting: (end, outcome).
    transmitting: Option<(Nanos, Conclusion)>,
    log: Vec<(Nanos, Vec<u8>)>,
    /// The link messages that reached its USART3 RX from its peer.
    link_gaps: LinkGaps,
}

/// How a transmission ends for its sender.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Conclusion {
    /// Sent and acknowledged.
    Sent,
    /// Nobody acknowledged it (the sender is cut off the bus: the hub's `mute`).
    NotAcknowledged,
    /// The bus model cannot carry it.
    Form,
    /// A bit error the network injected ([`Network::inject_bit_errors`]).
    BitError,
}

/// The network.
pub struct Network {
    mcus: Vec<Mcu>,
    bus: Bus,
    now: Nanos,
    quantum: Nanos,
    /// Frames on their way to the receivers.
    deliveries: Vec<Delivery>,
    /// External participants (tools), numbered after the MCUs, by name.
    externals: Vec<String>,
    /// Frames delivered to each external participant, oldest first.
    /// `None` once the participant left ([`Network::leave_external`]).
    inboxes: Vec<Option<std::collections::VecDeque<Delivery>>>,
    events: Vec<Event>,
    /// The bit rate the LSS master last configured (configure bit timing), in bit/s.
    master_rate: Option<u32>,
    /// The bus's switch to a new bit rate, when the master activated it: (when, bit/s).
    rate_switch: Option<(Nanos, u32)>,
}

fn instant(at: Nanos) -> Instant {
    Instant::from_micros(at.div_ceil(1_000))
}

fn nanos(at: Instant) -> Nanos {
    at.as_micros() * 1_000
}

/// The frame as the bus model carries it; `None` for an extended identifier.
fn to_bus(frame: &Frame) -> Option<CanFrame> {
    let Identifier::Standard(id) = frame.id else {
        return None;
    };
    let id = CanId::new(id).ok()?;
    if frame.remote {
        CanFrame::remote(id, frame.dlc.min(8)).ok()
    } else {
        CanFrame::new(id, &frame.data[..frame.data_len()]).ok()
    }
}

/// The frame as a CAN controller receives it.
fn from_bus(frame: &CanFrame) -> Frame {
    let id = Identifier::Standard(frame.id().raw());
    if frame.is_remote() {
        Frame::remote(id, frame.dlc())
    } else {
        Frame::data(id, frame.data())
    }
}

impl Network {
    /// The MCUs powered on at virtual time 0, on a bus at `bit_rate`, no links wired yet.
    pub fn new(members: Vec<Member>, bit_rate: u32) -> Result<Network, NetworkError> {
        let mut mcus = Vec::with_capacity(members.len());
        for member in members {
            let engine = |error| NetworkError::Engine {
                name: member.name.clone(),
                error,
            };
            let mut machine = Machine::new(Config { hse: member.hse }).map_err(engine)?;
            machine.load(&member.image).map_err(engine)?;
            {
                let mut port_c = machine.gpio(Port::C);
                for bit in 0..7 {
                    let closed = member.node_id.is_some_and(|id| id & (1 << bit) != 0);
                    port_c.drive(NODE_ID_PINS + bit, Some(closed));
                }
                port_c.drive(INPUT_PIN, Some(member.input_closed));
            }
            machine.reset().map_err(|stop| NetworkError::Reset {
                name: member.name.clone(),
                stop,
            })?;
            machine.yield_on_transmit_request(true);
            mcus.push(Mcu {
                name: member.name,
                machine,
                peer: None,
                link_cut: false,
                bit_errors: 0,
                stopped: false,
                output: false,
                offering_since: None,
                transmitting: None,
                log: Vec::new(),
                link_gaps: LinkGaps::default(),
            });
        }
        let mut bus = Bus::new(bit_rate, mcus.len());
        // Each MCU offers one frame at a time (its controller's best pending mailbox); a
        // tool's frames compete by identifier, as the hub queues them.
        bus.set_transmit_mailboxes(can_hub::bus::ORDERED_BY_IDENTIFIER);
        Ok(Network {
            mcus,
            bus,
            now: 0,
            quantum: DEFAULT_QUANTUM,
            deliveries: Vec::new(),
            externals: Vec::new(),
            inboxes: Vec::new(),
            events: Vec::new(),
            master_rate: None,
            rate_switch: None,
        })
    }

    /// Crosses the USART3s of MCUs `a` and `b` (the link between a node's two channels).
    pub fn link(&mut self, a: usize, b: usize) {
        self.mcus[a].peer = Some(b);
        self.mcus[b].peer = Some(a);
        self.mcus[a].machine.wire_usart();
        self.mcus[b].machine.wire_usart();
    }

    /// Cuts (or mends) the link wire from MCU `mcu`'s TX: its words are lost while cut.
    pub fn cut_link(&mut self, mcu: usize, cut: bool) {
        self.mcus[mcu].link_cut = cut;
    }

    /// The longest round, in virtual nanoseconds.
    pub fn quantum(&self) -> Nanos {
        self.quantum
    }

    /// Virtual time now: every MCU has run at least this far.
    pub fn now(&self) -> Nanos {
        self.now
    }

    /// The MCUs' names, in their order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.mcus.iter().map(|mcu| mcu.name.as_str())
    }

    /// MCU `mcu`'s machine (for reports: instructions, registers, the flash accelerator).
    pub fn machine(&self, mcu: usize) -> &Machine {
        &self.mcus[mcu].machine
    }

    /// The longest gap so far between two link messages that reached MCU `mcu`'s USART3 RX
    /// from its peer, in virtual time ([`LinkGaps`]): 0 until a first message came.
    pub fn longest_link_gap(&self, mcu: usize) -> Nanos {
        self.mcus[mcu].link_gaps.longest(self.now)
    }

    /// Whether MCU `mcu` stopped.
    pub fn stopped(&self, mcu: usize) -> bool {
        self.mcus[mcu].stopped
    }

    /// The bus (faults are injected here, with the hub's vocabulary).
    pub fn bus_mut(&mut self) -> &mut Bus {
        &mut self.bus
    }

    /// Hangs MCU `mcu`'s core for `duration` from now: no instruction, no interrupt, while
    /// its peripherals run on (a loop stuck with interrupts masked; [`Machine::hang`]).
    pub fn hang(&mut self, mcu: usize, duration: Nanos) {
        let until = self.now + duration;
        self.mcus[mcu].machine.hang(until);
    }

    /// Destroys MCU `mcu`'s next `count` transmissions with a bit error (ISO 11898-1 10.9.2:
    /// the sender reads a dominant level where it sent a recessive one, as a faulty
    /// transceiver or a short would make it): an error frame instead of the frame, no
    /// receiver takes it (each counts a receive error), the sender's TEC goes up by 8 each
    /// time (RM0090 32.7.6) and its controller retransmits, until it is error passive and then
    /// bus-off.
    pub fn inject_bit_errors(&mut self, mcu: usize, count: u32) {
        self.mcus[mcu].bit_errors = count;
    }

    /// Powers MCUs `mcus` off and on again (a node's supply failed and came back): each
    /// starts from its image with SRAM cleared and its flash as it stands
    /// ([`Machine::power_on_again`]), also one that had stopped.
    pub fn power_cycle(&mut self, mcus: &[usize]) {
        for &index in mcus {
            let at = self.now;
            let mcu = &mut self.mcus[index];
            mcu.transmitting = None;
            mcu.offering_since = None;
            mcu.bit_errors = 0;
            mcu.stopped = false;
            if let Err(stop) = mcu.machine.power_on_again() {
                mcu.stopped = true;
                self.events.push(Event::Stopped {
                    mcu: index,
                    stop,
                    at,
                });
            }
        }
    }

    /// Whether any MCU stopped (a fault, or the power cut armed in its flash).
    pub fn any_stopped(&self) -> bool {
        self.mcus.iter().any(|mcu| mcu.stopped)
    }

    /// MCU `mcu`'s machine, to arm a power cut in its flash.
    pub fn machine_mut(&mut self, mcu: usize) -> &mut Machine {
        &mut self.mcus[mcu].machine
    }

    /// Opens or closes MCU `mcu`'s safety input contact.
    pub fn set_input(&mut self, mcu: usize, closed: bool) {
        self.mcus[mcu]
            .machine
            .gpio(Port::C)
            .drive(INPUT_PIN, Some(closed));
    }

    /// MCU `mcu`'s safety output: the relay enabled.
    pub fn output(&self, mcu: usize) -> bool {
        self.mcus[mcu].output
    }

    /// A participant that is not an MCU (a tool on the socketcand port, a load generator):
    /// its number for [`Network::send`] and [`Network::receive`].
    pub fn join_external(&mut self, name: &str) -> usize {
        self.externals.push(name.to_owned());
        self.inboxes.push(Some(Default::default()));
        self.mcus.len() + self.externals.len() - 1
    }

    /// Queues `frame` from external participant `from` (by identifier, after the frames it
    /// queued before at the same identifier).
    pub fn send(&mut self, from: usize, frame: CanFrame) {
        self.bus.send(from, frame);
    }

    /// Whether external participant `from` can queue another frame: fewer than
    /// [`can_hub::bus::TRANSMIT_QUEUE`] of its frames wait for the bus. A sender from outside
    /// (a socketcand client) waits while it cannot, as on a real bus.
    pub fn has_room(&self, from: usize) -> bool {
        self.bus.has_room(from)
    }

    /// The oldest frame the bus delivered to external participant `participant` that it has
    /// not taken yet (every frame but its own), with the time it ended.
    pub fn receive(&mut self, participant: usize) -> Option<Delivery> {
        self.inboxes
            .get_mut(participant.checked_sub(self.mcus.len())?)?
            .as_mut()?
            .pop_front()
    }

    /// External participant `participant` stops listening: nothing more is kept for it (the
    /// frames it queued still go out, as a controller's transmit queue empties after its
    /// software stopped).
    pub fn leave_external(&mut self, participant: usize) {
        if let Some(inbox) = participant
            .checked_sub(self.mcus.len())
            .and_then(|index| self.inboxes.get_mut(index))
        {
            *inbox = None;
        }
    }

    /// Whether a frame waits for external participant `index` (counted among the external
    /// participants).
    fn has_frame_for(&self, index: usize) -> bool {
        self.inboxes
            .get(index)
            .and_then(Option::as_ref)
            .is_some_and(|inbox| !inbox.is_empty())
    }

    /// Runs until virtual time `end`, or until the end of the round in which a frame reached
    /// external participant `participant`. Returns whether one did.
    pub fn run_until_frame_for(&mut self, participant: usize, end: Nanos) -> bool {
        let Some(index) = participant.checked_sub(self.mcus.len()) else {
            self.run_until(end);
            return false;
        };
        while self.now < end {
            if self.has_frame_for(index) {
                return true;
            }
            self.round(self.horizon(end));
        }
        self.has_frame_for(index)
    }

    /// What happened since the last call, in time order.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    /// MCU `mcu`'s RTT bytes since the last call, with the time of each drain (decode them
    /// with its image's [`crate::log::LogTable`]).
    pub fn take_log(&mut self, mcu: usize) -> Vec<(Nanos, Vec<u8>)> {
        std::mem::take(&mut self.mcus[mcu].log)
    }

    /// The name of participant `from` (an MCU or an external participant).
    pub fn participant_name(&self, from: usize) -> String {
        match self.mcus.get(from) {
            Some(mcu) => mcu.name.clone(),
            None => self
                .externals
                .get(from - self.mcus.len())
                .cloned()
                .unwrap_or_else(|| format!("participant {from}")),
        }
    }

    /// The next instant the bus needs the MCUs to be at: a delivery or the end of a
    /// transmission.
    fn next_bus_event(&self) -> Option<Nanos> {
        let deliveries = self.deliveries.iter().map(|d| nanos(d.at));
        let ends = self
            .mcus
            .iter()
            .filter_map(|mcu| mcu.transmitting.map(|(end, _)| end));
        deliveries.chain(ends).min()
    }

    /// Runs every MCU until virtual time `end`.
    pub fn run_until(&mut self, end: Nanos) {
        while self.now < end {
            self.round(self.horizon(end));
        }
    }

    /// Where the next round ends: a quantum on, at the next bus event if sooner, at `end`
    /// at the latest.
    fn horizon(&self, end: Nanos) -> Nanos {
        let mut horizon = (self.now + self.quantum).min(end);
        if let Some(at) = self.next_bus_event() {
            horizon = horizon.min(at.max(self.now + 1));
        }
        horizon
    }

    /// One round: every MCU runs to `horizon`, then the bus and the links catch up.
    fn round(&mut self, horizon: Nanos) {
        let round_start = self.now;
        for index in 0..self.mcus.len() {
            let mcu = &mut self.mcus[index];
            if mcu.stopped {
                continue;
            }
            if mcu.offering_since.is_none() && mcu.machine.can().borrow().offer().is_some() {
                mcu.offering_since = Some(round_start);
            }
            loop {
                match mcu.machine.run_until(horizon) {
                    Outcome::Elapsed => break,
                    Outcome::Yielded => {
                        if mcu.offering_since.is_none() {
                            mcu.offering_since = Some(mcu.machine.now());
                        }
                    }
                    Outcome::Stopped {
                        stop: stop @ Stop::Reset { cause, .. },
                        at,
                    } => {
                        // The board starts again: the transmission in progress is lost
                        // with the controller's state.
                        mcu.transmitting = None;
                        mcu.offering_since = None;
                        let restarted = mcu.machine.system_reset(cause);
                        self.events.push(Event::Reset {
                            mcu: index,
                            stop,
                            at,
                        });
                        if let Err(stop) = restarted {
                            mcu.stopped = true;
                            self.events.push(Event::Stopped {
                                mcu: index,
                                stop,
                                at,
                            });
                            break;
                        }
                    }
                    Outcome::Stopped { stop, at } => {
                        mcu.stopped = true;
                        self.events.push(Event::Stopped {
                            mcu: index,
                            stop,
                            at,
                        });
                        break;
                    }
                }
            }
            let mcu = &mut self.mcus[index];
            mcu.log.extend(mcu.machine.take_log());
            let output = mcu.machine.gpio(Port::C).output_level(OUTPUT_PIN) == Some(true);
            if output != mcu.output {
                mcu.output = output;
                self.events.push(Event::Output {
                    at: horizon,
                    mcu: index,
                    on: output,
                });
            }
        }
        self.now = horizon;
        self.links();
        self.conclude_transmissions();
        self.deliver();
        self.switch_bit_rate();
        self.arbitrate();
    }

    /// Link words to the peers' RX, at the end of their stop bits.
    fn links(&mut self) {
        for index in 0..self.mcus.len() {
            let words = self.mcus[index].machine.take_usart_words();
            let (Some(peer), false) = (self.mcus[index].peer, self.mcus[index].link_cut) else {
                continue;
            };
            if self.mcus[peer].stopped {
                continue;
            }
            let receiver = &mut self.mcus[peer];
            for word in words {
                receiver.link_gaps.word(word.word, word.end);
                receiver.machine.usart_receive(word.word, word.end);
            }
        }
    }

    /// Transmissions whose frame ended by now: the sender learns the outcome.
    fn conclude_transmissions(&mut self) {
        for mcu in &mut self.mcus {
            let Some((end, conclusion)) = mcu.transmitting else {
                continue;
            };
            if end > self.now {
                continue;
            }
            mcu.transmitting = None;
            {
                let can = mcu.machine.can();
                let mut can = can.borrow_mut();
                match conclusion {
                    Conclusion::Sent => can.transmitted(end),
                    Conclusion::NotAcknowledged => can.error(BusError::Acknowledgment, end),
                    Conclusion::Form => can.error(BusError::Form, end),
                    Conclusion::BitError => can.error(BusError::BitDominant, end),
                }
            }
            mcu.machine.can_changed();
        }
    }

    /// The bus's part of CiA 305 Fig. 34 and 35: `frame`, ended at `at`, is an LSS request
    /// that configures or activates a bit rate for the master and the tools.
    fn follow_lss_master(&mut self, frame: &CanFrame, at: Nanos) {
        use shared::canopen::lss::{BitRate, MASTER_TO_SLAVE, specifier};
        if frame.id() != MASTER_TO_SLAVE || frame.data().len() != 8 {
            return;
        }
        let data = frame.data();
        match data[0] {
            specifier::CONFIGURE_BIT_TIMING => {
                self.master_rate = (data[1] == 0)
                    .then(|| BitRate::from_index(data[2]).and_then(BitRate::bits_per_second))
                    .flatten();
            }
            specifier::ACTIVATE_BIT_TIMING => {
                if let Some(rate) = self.master_rate {
                    let delay = u64::from(u16::from_le_bytes([data[1], data[2]]));
                    self.rate_switch = Some((at + delay * 1_000_000, rate));
                }
            }
            _ => {}
        }
    }

    /// The bus takes the rate the master activated, once its switch delay has passed.
    fn switch_bit_rate(&mut self) {
        let Some((at, bit_rate)) = self.rate_switch else {
            return;
        };
        if at > self.now {
            return;
        }
        self.rate_switch = None;
        self.bus.set_bit_rate(bit_rate);
        self.events.push(Event::BitRate { at, bit_rate });
    }

    /// The bus's bit rate now.
    pub fn bit_rate(&self) -> u32 {
        self.bus.bit_rate()
    }

    /// Frames that reached their receivers by now.
    fn deliver(&mut self) {
        let now = instant(self.now);
        let (due, later): (Vec<_>, Vec<_>) = self.deliveries.drain(..).partition(|d| d.at <= now);
        self.deliveries = later;
        for delivery in due {
            let at = nanos(delivery.at);
            self.events.push(Event::Frame {
                at,
                from: self.participant_name(delivery.from),
                frame: delivery.frame,
            });
            self.follow_lss_master(&delivery.frame, at);
            let frame = from_bus(&delivery.frame);
            let bit_rate = self.bus.bit_rate();
            for (index, mcu) in self.mcus.iter_mut().enumerate() {
                if index == delivery.from || mcu.stopped {
                    continue;
                }
                {
                    let can = mcu.machine.can();
                    let mut can = can.borrow_mut();
                    if in_step(can.bits_duration(STEP_BITS), STEP_BITS, bit_rate) {
                        can.deliver(&frame, at);
                    } else {
                        can.receive_error(BusError::Form, at);
                    }
                }
                mcu.machine.can_changed();
            }
            for (external, inbox) in self.inboxes.iter_mut().enumerate() {
                if let Some(inbox) = inbox
                    && self.mcus.len() + external != delivery.from
                {
                    inbox.push_back(delivery);
                }
            }
        }
    }

    /// When the bus is free: the MCUs' offers join the tools' queued frames, and the lowest
    /// identifier starts at the earliest instant an offer was made (not before the bus was
    /// free).
    fn arbitrate(&mut self) {
        let free_at = nanos(self.bus.free_at());
        if free_at > self.now {
            return;
        }
        let mut earliest: Option<Nanos> = None;
        let mut offers: Vec<Option<CanFrame>> = vec![None; self.mcus.len()];
        for (index, mcu) in self.mcus.iter_mut().enumerate() {
            self.bus.leave(index);
            let offer = if mcu.stopped {
                None
            } else {
                mcu.machine.can().borrow().offer()
            };
            let Some(offer) = offer else {
                mcu.offering_since = None;
                continue;
            };
            let since = mcu.offering_since.unwrap_or(self.now);
            let out_of_step = {
                let can = mcu.machine.can();
                let can = can.borrow();
                (!in_step(can.bits_duration(STEP_BITS), STEP_BITS, self.bus.bit_rate()))
                    .then(|| can.frame_duration(&offer))
            };
            if let Some(duration) = out_of_step {
                // Nobody on the bus reads its bits: no acknowledgement, and its frame is not
                // the bus's (see the module's "Bit rate").
                let start = since.max(self.now);
                mcu.machine.can().borrow_mut().start_transmission(start);
                mcu.transmitting = Some((start + duration, Conclusion::NotAcknowledged));
                mcu.offering_since = None;
                continue;
            }
            earliest = Some(earliest.map_or(since, |e| e.min(since)));
            match to_bus(&offer) {
                Some(frame) => {
                    offers[index] = Some(frame);
                    self.bus.send(index, frame);
                }
                None => {
                    // Ended at once with a form error for its sender; it never wins.
                    let start = since.max(free_at);
                    let can = mcu.machine.can();
                    can.borrow_mut().start_transmission(start);
                    mcu.transmitting = Some((start + 1, Conclusion::Form));
                    mcu.offering_since = None;
                    self.events.push(Event::Refused {
                        mcu: index,
                        at: start,
                        frame: offer,
                    });
                }
            }
        }
        let externals_waiting = (self.mcus.len()..self.mcus.len() + self.externals.len())
            .any(|p| self.bus.queued(p) > 0);
        if externals_waiting {
            earliest = Some(earliest.map_or(self.now, |e| e.min(self.now)));
        }
        let Some(earliest) = earliest else {
            return;
        };
        let start = instant(earliest.max(free_at));
        let first = self.deliveries.len();
        self.bus.arbitrate_into(start, &mut self.deliveries);
        let end = self.bus.free_at();
        let winner = (0..self.mcus.len()).find(|&i| offers[i].is_some() && self.bus.queued(i) == 0);
        let destroyed = winner.is_some_and(|w| self.mcus[w].bit_errors > 0) && end > start;
        if destroyed {
            // The error frame replaces the frame: nobody receives it (each receiver counts a
            // receive error), the bus is taken for as long (an approximation: an error frame
            // is 14 to 20 bits after the bit in error).
            self.deliveries.truncate(first);
            for (index, mcu) in self.mcus.iter_mut().enumerate() {
                if Some(index) != winner && !mcu.stopped {
                    mcu.machine
                        .can()
                        .borrow_mut()
                        .receive_error(BusError::Form, nanos(end));
                    mcu.machine.can_changed();
                }
            }
        }
        let start_nanos = nanos(start);
        for (index, mcu) in self.mcus.iter_mut().enumerate() {
            let Some(offer) = offers[index] else {
                continue;
            };
            let can = mcu.machine.can();
            let mut can = can.borrow_mut();
            can.start_transmission(start_nanos);
            if Some(index) == winner {
                let (conclude_at, conclusion) = if end <= start {
                    // The hub's `mute`: the frame never reaches the bus (the bus stays
                    // free), so nobody acknowledges it; the sender's error comes at the ACK
                    // slot, about the frame's length later.
                    let bits = u64::from(can_hub::bus::frame_bits(&offer));
                    (
                        start_nanos + bits * 1_000_000_000 / u64::from(self.bus.bit_rate()),
                        Conclusion::NotAcknowledged,
                    )
                } else if destroyed {
                    mcu.bit_errors -= 1;
                    (nanos(end), Conclusion::BitError)
                } else {
                    (nanos(end), Conclusion::Sent)
                };
                mcu.transmitting = Some((conclude_at, conclusion));
                mcu.offering_since = None;
            } else {
                // Lost arbitration within the identifier (RM0090 32.7.1: ALST); it stays
                // pending and competes again when the bus is free.
                can.lost_arbitration(start_nanos);
                drop(can);
                mcu.machine.can_changed();
            }
            self.bus.leave(index);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ISO 11898-1's oscillator tolerance: a controller within it keeps step with the bus, one
    /// beyond it (or at another rate of the table) does not.
    #[test]
    fn rm0090_32_7_7_a_controller_keeps_step_with_the_bus_only_within_the_oscillator_tolerance() {
        let bus_ns = |bits: u64, rate: u64| bits * 1_000_000_000 / rate;
        assert!(in_step(bus_ns(STEP_BITS, 500_000), STEP_BITS, 500_000));
        // 1.5 % slow and fast: within.
        assert!(in_step(
            bus_ns(STEP_BITS, 500_000) * 1015 / 1000,
            STEP_BITS,
            500_000
        ));
        assert!(in_step(
            bus_ns(STEP_BITS, 500_000) * 985 / 1000,
            STEP_BITS,
            500_000
        ));
        // 1.7 %: out of step.
        assert!(!in_step(
            bus_ns(STEP_BITS, 500_000) * 1017 / 1000,
            STEP_BITS,
            500_000
        ));
        // The controller at 500 kbit/s, the bus switched to 250 kbit/s, and back.
        assert!(!in_step(bus_ns(STEP_BITS, 500_000), STEP_BITS, 250_000));
        assert!(!in_step(bus_ns(STEP_BITS, 250_000), STEP_BITS, 500_000));
    }
}
