//! A CANopen Safety network under simulated time: devices running the real protocol core, a
//! configuration tool (participant 0) that talks SDO and NMT over the same bus (the tool
//! library, `safety_config`, through [`crate::tool_bus`]), and the [`Bus`] between them. Deterministic: the same scenario gives the same trace, to the
//! microsecond.

use crate::bus::{Bus, Delivery, Fault, Injection, Match};
use crate::tool_bus::{client, sdo_error};
use safety_config::ToolError;
use safety_config::procedure;
use shared::canopen::NodeId;
use shared::canopen::emcy::Emergency;
use shared::canopen::nmt::{self, NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::canopen::sdo_client::ClientError;
use shared::canopen::storage::RamFlash;
use shared::node::{Event, Node, NodeConfig, Sink};
use shared::safety::config::SrdoRecord;
use shared::{CanFrame, Duration, Instant};
use std::fmt::Write as _;

/// The node type of the simulated devices: up to 4 SRDOs, 8 KiB per storage slot.
pub type DeviceNode = Node<RamFlash<8192>, 4>;

pub use safety_device::{INPUT, INPUT_INVERTED, OBJECTS, OUTPUT};

/// The device description for node `id`.
pub fn device_config(id: u8, name: &'static str) -> NodeConfig {
    safety_device::config(NodeId::new(id).expect("node-ID 1..=127"), name)
}

/// Something that happened on the network, for the log and the assertions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Happening {
    /// A device reported an event.
    Event(Event),
    /// A device's output object changed to this value.
    Output(u8),
    /// The tool saw an EMCY from a node.
    Emergency(u8, Emergency),
}

/// One simulated device with what it reported.
pub struct Device {
    /// A name for the log.
    pub name: &'static str,
    /// The protocol core.
    pub node: DeviceNode,
    deadline: Instant,
    output: u8,
    /// SRDO pairs received and delivered.
    pub pairs_received: u64,
}

/// What a device hands out during one call, gathered and then applied to the network.
#[derive(Default)]
struct Outbox {
    frames: Vec<CanFrame>,
    events: Vec<Event>,
}

impl Sink for Outbox {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn event(&mut self, event: Event) {
        self.events.push(event);
    }
}

/// The network: participant 0 is the tool, participant `i + 1` is `devices[i]`.
pub struct Network {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The devices.
    pub devices: Vec<Device>,
    in_flight: Vec<Delivery>,
    /// Everything that happened, in order: (time, device index or `None` for the tool, what).
    pub log: Vec<(Instant, Option<usize>, Happening)>,
    /// Every frame as received, in candump order.
    pub trace: Vec<(Instant, CanFrame)>,
}

impl Network {
    /// Devices `(node-ID, name)` on a bus at `bit_rate`, all powered on at t = 0.
    pub fn new(bit_rate: u32, devices: &[(u8, &'static str)]) -> Self {
        let devices = devices
            .iter()
            .map(|&(id, name)| Device {
                name,
                node: DeviceNode::new(device_config(id, name), RamFlash::new())
                    .expect("valid device description"),
                deadline: Instant::ZERO,
                output: 0,
                pairs_received: 0,
            })
            .collect::<Vec<_>>();
        Network {
            now: Instant::ZERO,
            bus: Bus::new(bit_rate, devices.len() + 1),
            devices,
            in_flight: Vec::new(),
            log: Vec::new(),
            trace: Vec::new(),
        }
    }

    /// `count` devices on a bus at `bit_rate` whose LSS slave is enabled (CiA 305, the
    /// `shared` feature `lss`) with their node-ID switches open and nothing stored: each is
    /// unconfigured (node-ID FFh) and silent but for LSS until a master gives it a node-ID.
    /// Their identities are the device's (`safety_device::config`) with serial
    /// numbers 1 to `count`; each can be set to every bit rate of the bus model.
    pub fn unconfigured_lss(bit_rate: u32, count: u8) -> Self {
        use shared::canopen::lss::{BitRate, BitRates};
        let rates = BitRates::of(&[
            BitRate::Kbit1000,
            BitRate::Kbit500,
            BitRate::Kbit250,
            BitRate::Kbit125,
        ]);
        let devices: Vec<(u8, &'static str)> =
            (1..=count).map(|serial| (serial, "LSS node")).collect();
        let mut net = Network::new(bit_rate, &devices);
        for device in &mut net.devices {
            let enabled = device.node.enable_lss(None, rates);
            assert!(enabled, "LSS is enabled before the first poll");
        }
        net
    }

    /// The device with node-ID `id`.
    pub fn index_of(&self, id: u8) -> usize {
        self.devices
            .iter()
            .position(|device| device.node_id() == id)
            .expect("a device with this node-ID")
    }

    /// Runs the network until `end`.
    pub fn run_until(&mut self, end: Instant) {
        loop {
            let next = self.next_activity();
            if next > end {
                self.now = end.max(self.now);
                return;
            }
            self.now = next.max(self.now);
            self.step();
        }
    }

    /// Runs the network for `duration`.
    pub fn run_for(&mut self, duration: Duration) {
        self.run_until(self.now + duration);
    }

    fn next_activity(&self) -> Instant {
        let deliveries = self.in_flight.iter().map(|delivery| delivery.at);
        let deadlines = self.devices.iter().map(|device| device.deadline);
        let bus = self.bus.next_start(self.now);
        deliveries
            .chain(deadlines)
            .chain(bus)
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Everything due at `self.now`: deliveries, then timers, then the next arbitration.
    fn step(&mut self) {
        let now = self.now;
        let (due, later): (Vec<_>, Vec<_>) = self
            .in_flight
            .drain(..)
            .partition(|delivery| delivery.at <= now);
        self.in_flight = later;
        for delivery in due {
            self.trace.push((delivery.at, delivery.frame));
            if delivery.from != 0 {
                self.tool_receives(delivery.at, delivery.frame, delivery.from - 1);
            }
            for index in 0..self.devices.len() {
                if index + 1 != delivery.from {
                    self.with_device(index, |node, now, outbox| {
                        node.handle_frame(now, &delivery.frame, outbox);
                    });
                }
            }
        }
        for index in 0..self.devices.len() {
            if self.devices[index].deadline <= now {
                self.with_device(index, |_, _, _| {});
            }
        }
        if self.bus.next_start(now) == Some(now) {
            let deliveries = self.bus.arbitrate(now);
            self.in_flight.extend(deliveries);
        }
    }

    /// Calls `action` on device `index`, then polls it, and applies what it handed out.
    fn with_device(
        &mut self,
        index: usize,
        action: impl FnOnce(&mut DeviceNode, Instant, &mut Outbox),
    ) {
        let now = self.now;
        let mut outbox = Outbox::default();
        let device = &mut self.devices[index];
        action(&mut device.node, now, &mut outbox);
        device.deadline = device.node.poll(now, &mut outbox);
        let mut buf = [0u8; 1];
        let output = device
            .node
            .read_object(OUTPUT, &mut buf)
            .map_or(0, |_| buf[0]);
        let changed = output != device.output;
        device.output = output;
        for event in &outbox.events {
            if matches!(event, Event::SrdoReceived { .. }) {
                device.pairs_received += 1;
            }
        }
        for frame in outbox.frames {
            self.bus.send(index + 1, frame);
        }
        for event in outbox.events {
            self.log.push((now, Some(index), Happening::Event(event)));
        }
        if changed {
            self.log.push((now, Some(index), Happening::Output(output)));
        }
    }

    fn tool_receives(&mut self, at: Instant, frame: CanFrame, device: usize) {
        let id = frame.id().raw();
        if (0x081..=0x0FF).contains(&id) {
            if let Some(emergency) = Emergency::parse(frame.data()) {
                let node = (id - 0x080) as u8;
                self.log
                    .push((at, Some(device), Happening::Emergency(node, emergency)));
            }
        }
    }

    /// The application of device `index` sets its safety input: the plain value and its
    /// inverted copy, as the two channels would (here in one step).
    pub fn set_input(&mut self, index: usize, value: u8) {
        self.with_device(index, |node, _, _| {
            node.write_object(INPUT, &[value]).expect("input object");
            node.write_object(INPUT_INVERTED, &[!value])
                .expect("input object");
        });
    }

    /// The output object of device `index`.
    pub fn output(&self, index: usize) -> u8 {
        self.devices[index].output
    }

    /// The tool sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
        self.run_for(Duration::from_millis(1));
    }

    /// Adds a fault on the bus.
    pub fn inject(&mut self, when: Match, fault: Fault) {
        self.bus.inject(Injection::new(when, fault));
    }

    /// SDO download from the tool (the tool library's client, `safety_config::client`).
    pub fn write(&mut self, id: u8, address: Address, data: &[u8]) -> Result<(), ClientError> {
        client(self).write(id, address, data).map_err(sdo_error)
    }

    /// SDO upload from the tool (the tool library's client).
    pub fn read(&mut self, id: u8, address: Address) -> Result<Vec<u8>, ClientError> {
        client(self).read(id, address).map_err(sdo_error)
    }

    /// The tool reads SRDO `n`'s whole record back from node `id`
    /// (`safety_config::procedure::read_record`), as shared's record type.
    pub fn read_srdo(&mut self, id: u8, n: u16) -> Result<SrdoRecord, ClientError> {
        let n = u8::try_from(n).map_err(|_| ClientError::Protocol)?;
        let held = procedure::read_record(&mut client(self), id, n).map_err(sdo_error)?;
        let settings = held.settings;
        let mut record = SrdoRecord {
            direction: settings.direction,
            cycle_time: settings.cycle_time,
            srvt: settings.srvt,
            cob_id_1: settings.cob_id_1,
            cob_id_2: settings.cob_id_2,
            mapping_count: settings.mapping.len() as u8,
            ..SrdoRecord::DELETED
        };
        for (slot, entry) in record.mapping.iter_mut().zip(&settings.mapping) {
            *slot = *entry;
        }
        Ok(record)
    }

    /// The tool signs SRDOs `srdos` of node `id` over their read-back values with its own
    /// CRC (EN 50325-5 6.4.1.5), writes and reads back 0x13FF, and declares the
    /// configuration valid (0x13FE = A5h, read back): `safety_config::procedure::
    /// sign_and_validate`.
    pub fn sign_and_validate(&mut self, id: u8, srdos: &[u16]) -> Result<(), ToolError> {
        let srdos: Vec<u8> = srdos
            .iter()
            .map(|&n| {
                u8::try_from(n)
                    .map_err(|_| ToolError::Usage(format!("there is no SRDO {n} (1..=64)")))
            })
            .collect::<Result<_, _>>()?;
        procedure::sign_and_validate(&mut client(self), id, &srdos).map(|_| ())
    }

    /// The NMT state of device `index`.
    pub fn state(&self, index: usize) -> NmtState {
        self.devices[index].node.nmt_state()
    }

    /// The log from `since` on, as text lines (valid SRDO pairs are counted, not listed).
    pub fn describe(&self, since: usize) -> String {
        let mut text = String::new();
        for (at, device, happening) in &self.log[since.min(self.log.len())..] {
            if matches!(happening, Happening::Event(Event::SrdoReceived { .. })) {
                // Counted per device; one line per pair would drown the rest.
                continue;
            }
            let who = device.map_or("tool", |index| self.devices[index].name);
            let _ = writeln!(
                text,
                "{:>10.3} ms  {who:<14} {}",
                at.as_micros() as f64 / 1000.0,
                describe(happening)
            );
        }
        text
    }

    /// The trace in candump log format (`(seconds) can0 ID#DATA`), written by the tool's
    /// monitor's writer, which also replays it.
    pub fn candump(&self) -> String {
        let mut text = String::new();
        for (at, frame) in &self.trace {
            let since_start = std::time::Duration::from_micros(at.as_micros());
            text.push_str(&safety_config::monitor::candump::line(
                since_start,
                "can0",
                frame,
            ));
            text.push('\n');
        }
        text
    }
}

impl Device {
    /// The device's node-ID.
    pub fn node_id(&self) -> u8 {
        self.node.node_id().raw()
    }
}

/// A human-readable line for a happening.
pub fn describe(happening: &Happening) -> String {
    match happening {
        Happening::Event(Event::NmtState(state)) => format!("NMT state {state:?}"),
        Happening::Event(Event::SrdoFault(fault)) => format!(
            "SRDO {} FAULT: {:?} -> safe state",
            fault.srdo.get(),
            fault.cause
        ),
        Happening::Event(event) => format!("{event:?}"),
        Happening::Output(value) => format!(
            "output 0x6200:1 = {value} ({})",
            if *value == 0 {
                "SAFE STATE"
            } else {
                "machine enabled"
            }
        ),
        Happening::Emergency(node, emergency) => format!(
            "EMCY from node {node}: code {:04X}h, register {:02X}h, detail {:02X?}",
            emergency.code, emergency.register, emergency.detail
        ),
    }
}
