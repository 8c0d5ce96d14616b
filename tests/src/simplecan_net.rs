//! A SimpleCAN network under simulated time: devices running the protocol core with the SRDO
//! table and SimpleCAN in their slot ([`SimpleCanNode`]), configured by SDO over the same bus
//! by the tool library's client (participant 0), on the simulated [`Bus`] with bit time and
//! arbitration. Deterministic, to the microsecond.
//!
//! Each device's controller is modelled as SimpleCAN needs it: one frame at a time on the bus
//! (the lowest identifier of those waiting goes first, as `board::hw`'s transmit queue), a
//! confirmation when the frame has been on the bus ([`shared::node::Device::on_transmitted`]),
//! and [`Sink::abort`] withdrawing frames that have not started (SC_REQ_18, SC_REQ_23). A
//! device can be switched off (it leaves the bus) and on (a new device on the same flash).

use crate::bus::{Bus, Delivery};
use crate::tool_bus::{Simulation, client, sdo_error};
use shared::canopen::NodeId;
use shared::canopen::nmt::{self, NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::canopen::sdo_client::ClientError;
use shared::canopen::storage::RamFlash;
use shared::frame::CanId;
use shared::node::simplecan::{
    COUNT_INDEX, CYCLE_INDEX, FIRST_ENTRY_INDEX, SIGNATURE_INDEX, VALID_INDEX,
};
use shared::node::{Event, NodeConfig, SimpleCanNode, Sink};
use shared::{CanFrame, Duration, Instant};

pub use shared::node::simplecan::{ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE};

/// The device: 4 SRDOs and 4 SDD entries, 8 KiB per storage slot.
pub type ScDevice = SimpleCanNode<RamFlash<8192>, 4, 4>;

/// The input a producer maps (6000h:01, 8 bits) and the outputs a consumer maps (6200h:01,
/// 6201h:01).
pub const INPUT: u32 = 0x6000_0108;
/// The first output.
pub const OUTPUT_1: u32 = 0x6200_0108;
/// The second output.
pub const OUTPUT_2: u32 = 0x6201_0108;

/// The node hash the "tool" gives an SC-ID in these networks (SC_REQ_15: one per SC-ID,
/// different for different SC-IDs).
pub fn node_hash(sc_id: u8) -> u32 {
    0xC0DE_0000 | (u32::from(sc_id) * 0x0101)
}

/// One SDD entry as the tool writes it.
#[derive(Clone, Copy, Debug)]
pub struct ScEntry {
    /// The SC-ID.
    pub sc_id: u8,
    /// [`ROLE_PRODUCE`], [`ROLE_CONSUME`] or [`ROLE_MASTER`].
    pub role: u8,
    /// The producer's slot.
    pub slot: u16,
    /// The safety timeout in ms (consumed entries).
    pub timeout_ms: u16,
    /// The mapped object.
    pub mapped: u32,
}

/// The emergency stop of the two-node examples (node 1 → node 33): SC-ID 30h.
pub const ESTOP: u8 = 0x30;

impl ScEntry {
    /// Node 1's entry of the emergency stop: it produces [`ESTOP`] in slot 0 from [`INPUT`].
    pub const ESTOP_PRODUCER: ScEntry = ScEntry {
        sc_id: ESTOP,
        role: ROLE_PRODUCE,
        slot: 0,
        timeout_ms: 0,
        mapped: INPUT,
    };

    /// Node 33's entry of the emergency stop: it consumes [`ESTOP`] into [`OUTPUT_1`] with a
    /// 50 ms safety timeout (SC_REQ_20).
    pub const ESTOP_CONSUMER: ScEntry = ScEntry {
        sc_id: ESTOP,
        role: ROLE_CONSUME,
        slot: 0,
        timeout_ms: 50,
        mapped: OUTPUT_1,
    };
}

/// A device's SimpleCAN configuration.
#[derive(Clone, Debug)]
pub struct ScConfig {
    /// Slots per cycle.
    pub slots: u16,
    /// Cycles between syncs.
    pub sync_every: u16,
    /// The guaranteed maximum buffering time in µs (SC_REQ_33). A sync's time is taken when
    /// the master hands it to its controller and is handed in to a receiver at the end of the
    /// frame: the frame's own time on the bus belongs in it.
    pub buffering_us: u16,
    /// Potential master.
    pub potential_master: bool,
    /// The entries.
    pub entries: Vec<ScEntry>,
}

/// One simulated device.
pub struct ScNetDevice {
    /// The node-ID.
    pub id: u8,
    /// The protocol core (`None` while switched off).
    pub node: Option<ScDevice>,
    flash: RamFlash<8192>,
    deadline: Instant,
    /// Frames handed out and not yet on the bus, the one competing for it included.
    waiting: Vec<CanFrame>,
    /// The frame handed to the bus, until its delivery.
    on_bus: Option<CanFrame>,
    /// Every event it reported, with the instant.
    pub events: Vec<(Instant, Event)>,
    /// Its first output (6200h:01) whenever it changed, with the instant.
    pub outputs: Vec<(Instant, u8)>,
}

/// What a device hands out during one call.
#[derive(Default)]
struct Outbox {
    frames: Vec<CanFrame>,
    events: Vec<Event>,
    aborts: Vec<CanId>,
}

impl Sink for Outbox {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn event(&mut self, event: Event) {
        self.events.push(event);
    }
    fn abort(&mut self, id: CanId) {
        self.aborts.push(id);
    }
}

/// The network: participant 0 is the tool, participant `i + 1` is `devices[i]`.
pub struct ScNetwork {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The devices.
    pub devices: Vec<ScNetDevice>,
    in_flight: Vec<Delivery>,
    /// Every frame on the bus: when its transmission started, when it ended, who sent it
    /// (0: the tool).
    pub trace: Vec<(Instant, Instant, CanFrame, usize)>,
    /// Frames that every receiver loses: the sender's controller confirms them, no device
    /// receives them ([`ReceiveLoss`]; they stay in `trace`, which is the bus).
    pub receive_loss: Vec<ReceiveLoss>,
}

/// Frames of one identifier lost by every receiver while they end within `[from, until)`:
/// the sender sees them go out (it is told they were transmitted), no other device gets
/// them, as when every receiver's path to the bus loses them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReceiveLoss {
    /// The identifier.
    pub id: u16,
    /// From this instant on (frame ends).
    pub from: Instant,
    /// Until this instant (excluded).
    pub until: Instant,
}

impl ReceiveLoss {
    /// Whether every receiver loses `frame`, which ended at `end`.
    pub fn loses(&self, frame: &CanFrame, end: Instant) -> bool {
        frame.id().raw() == self.id && end >= self.from && end < self.until
    }
}

/// The device description of node `id`.
pub fn device_config(id: u8) -> NodeConfig {
    safety_device::config(
        NodeId::new(id).expect("node-ID 1..=127"),
        safety_device::CHANNEL_A_NAME,
    )
}

impl ScNetwork {
    /// Devices with node-IDs `ids` on a bus at `bit_rate`, all powered on at t = 0.
    pub fn new(bit_rate: u32, ids: &[u8]) -> Self {
        let devices = ids
            .iter()
            .map(|&id| ScNetDevice {
                id,
                node: Some(
                    ScDevice::new(device_config(id), RamFlash::new()).expect("valid device"),
                ),
                flash: RamFlash::new(),
                deadline: Instant::ZERO,
                waiting: Vec::new(),
                on_bus: None,
                events: Vec::new(),
                outputs: Vec::new(),
            })
            .collect::<Vec<_>>();
        ScNetwork {
            now: Instant::ZERO,
            bus: Bus::new(bit_rate, devices.len() + 1),
            devices,
            in_flight: Vec::new(),
            trace: Vec::new(),
            receive_loss: Vec::new(),
        }
    }

    /// The index of the device with node-ID `id`.
    pub fn index_of(&self, id: u8) -> usize {
        self.devices
            .iter()
            .position(|device| device.id == id)
            .expect("a device with this node-ID")
    }

    /// The protocol core of node `id` (switched on).
    pub fn node(&self, id: u8) -> &ScDevice {
        self.devices[self.index_of(id)]
            .node
            .as_ref()
            .expect("switched on")
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
        let deadlines = self
            .devices
            .iter()
            .filter(|device| device.node.is_some())
            .map(|device| device.deadline);
        deliveries
            .chain(deadlines)
            .chain(self.bus.next_start(self.now))
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Everything due at `self.now`: deliveries (and the sender's confirmation), timers,
    /// then the next arbitration.
    fn step(&mut self) {
        let now = self.now;
        let (due, later): (Vec<_>, Vec<_>) = self
            .in_flight
            .drain(..)
            .partition(|delivery| delivery.at <= now);
        self.in_flight = later;
        for delivery in due {
            let bits = u64::from(delivery.bits);
            let started = Instant::from_micros(
                delivery.at.as_micros() - bits * 1_000_000 / u64::from(self.bus.bit_rate()),
            );
            self.trace
                .push((started, delivery.at, delivery.frame, delivery.from));
            if delivery.from != 0 {
                let sender = delivery.from - 1;
                self.devices[sender].on_bus = None;
                self.with_device(sender, |node, now, outbox| {
                    node.on_transmitted(now, &delivery.frame, outbox);
                });
            }
            let lost = self
                .receive_loss
                .iter()
                .any(|loss| loss.loses(&delivery.frame, delivery.at));
            for index in 0..self.devices.len() {
                if index + 1 != delivery.from && !lost {
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

    /// Calls `action` on device `index` (if switched on), polls it, and applies what it
    /// handed out: frames to its controller, aborts to what has not started, events logged.
    fn with_device(
        &mut self,
        index: usize,
        action: impl FnOnce(&mut ScDevice, Instant, &mut Outbox),
    ) {
        let now = self.now;
        let device = &mut self.devices[index];
        let Some(node) = device.node.as_mut() else {
            return;
        };
        let mut outbox = Outbox::default();
        action(node, now, &mut outbox);
        device.deadline = node.poll(now, &mut outbox);
        let mut output = [0u8];
        let _ = node.read_object(Address::new(0x6200, 1), &mut output);
        if device.outputs.last().map(|&(_, value)| value) != Some(output[0]) {
            device.outputs.push((now, output[0]));
        }
        device.waiting.extend(outbox.frames);
        for id in outbox.aborts {
            device.waiting.retain(|frame| frame.id() != id);
            if device.on_bus.is_some_and(|frame| frame.id() == id) {
                // Not yet arbitrated (a frame that has won the bus is in flight and cannot
                // be withdrawn): the participant's queue holds only this frame.
                self.bus.leave(index + 1);
                device.on_bus = None;
            }
        }
        device
            .events
            .extend(outbox.events.into_iter().map(|event| (now, event)));
        if device.on_bus.is_none()
            && let Some(position) = (0..device.waiting.len())
                .min_by_key(|&position| device.waiting[position].id().raw())
        {
            let frame = device.waiting.remove(position);
            device.on_bus = Some(frame);
            self.bus.send(index + 1, frame);
        }
    }

    /// Switches node `id` off: it leaves the bus, with everything it had queued.
    pub fn switch_off(&mut self, id: u8) {
        let index = self.index_of(id);
        let device = &mut self.devices[index];
        if let Some(node) = device.node.take() {
            device.flash = node.flash().clone();
        }
        device.waiting.clear();
        device.on_bus = None;
        self.bus.leave(index + 1);
    }

    /// Switches node `id` on again: a new device on its flash (its stored parameters).
    pub fn switch_on(&mut self, id: u8) {
        let index = self.index_of(id);
        let device = &mut self.devices[index];
        device.node =
            Some(ScDevice::new(device_config(id), device.flash.clone()).expect("valid device"));
        device.deadline = self.now;
    }

    /// Sets the input object (6000h:01) of node `id`, as the application does.
    pub fn set_input(&mut self, id: u8, value: u8) {
        let index = self.index_of(id);
        self.with_device(index, |node, _, _| {
            node.write_object(Address::new(0x6000, 1), &[value])
                .expect("input object");
        });
    }

    /// The tool sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
        self.run_for(Duration::from_millis(1));
    }

    /// SDO download from the tool.
    pub fn write(&mut self, id: u8, address: Address, data: &[u8]) -> Result<(), ClientError> {
        client(self).write(id, address, data).map_err(sdo_error)
    }

    /// SDO upload from the tool.
    pub fn read(&mut self, id: u8, address: Address) -> Result<Vec<u8>, ClientError> {
        client(self).read(id, address).map_err(sdo_error)
    }

    /// Configures node `id` as a tool does ([`configure`]).
    pub fn configure(&mut self, id: u8, config: &ScConfig) -> Result<(), String> {
        configure(self, id, config)
    }

    /// The SimpleCAN frames on the bus of identifier `id`: (start, end) of each.
    pub fn sent(&self, id: u16) -> Vec<(Instant, Instant, CanFrame)> {
        self.trace
            .iter()
            .filter(|(_, _, frame, _)| frame.id().raw() == id)
            .map(|&(start, end, frame, _)| (start, end, frame))
            .collect()
    }

    /// The latched safe-state cause code of node `id`, if a SimpleCAN one.
    pub fn protocol_cause(&self, id: u8) -> Option<u8> {
        match self.node(id).fault() {
            Some(shared::node::SafeStateCause::Protocol { cause, .. }) => Some(cause),
            _ => None,
        }
    }

    /// The NMT state of node `id`.
    pub fn state(&self, id: u8) -> NmtState {
        self.node(id).nmt_state()
    }
}

/// CRC-32/MPEG-2 bit by bit: polynomial 04C11DB7h, initial value FFFFFFFFh, MSB first, no
/// final XOR (`docs/simplecan.md` section 11), a second implementation beside the device's.
pub fn crc32_mpeg2(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in bytes {
        crc ^= u32::from(byte) << 24;
        for _ in 0..8 {
            crc = if crc & 0x8000_0000 != 0 {
                (crc << 1) ^ 0x04C1_1DB7
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Configures node `id` as a tool does (SC_REQ_35, SC_REQ_36): its SRDOs deleted and
/// the SRDO table declared valid; SimpleCAN's objects written, the count last; every
/// object read back and compared; the signature computed from the values read back by a
/// bit-by-bit CRC-32 of its own (not the device's), written, then 5EFEh = A5h; stored.
/// The network may be any simulated one the tool reaches ([`Simulation`]): this one, or
/// one of dual-channel nodes (`crate::simplecan_dual`).
pub fn configure(net: &mut impl Simulation, id: u8, config: &ScConfig) -> Result<(), String> {
    let fail = |what: &str, error: ClientError| format!("node {id}: {what}: {error:?}");
    for n in 0..4u16 {
        sdo_write(net, id, Address::new(0x1301 + n, 1), &[0])
            .map_err(|e| fail("deleting an SRDO", e))?;
    }
    sdo_write(net, id, Address::new(0x13FE, 0), &[0xA5]).map_err(|e| fail("13FEh", e))?;
    let mut writes: Vec<(Address, Vec<u8>)> = vec![
        (
            Address::new(CYCLE_INDEX, 1),
            config.slots.to_le_bytes().to_vec(),
        ),
        (
            Address::new(CYCLE_INDEX, 2),
            config.sync_every.to_le_bytes().to_vec(),
        ),
        (
            Address::new(CYCLE_INDEX, 3),
            config.buffering_us.to_le_bytes().to_vec(),
        ),
        (Address::new(CYCLE_INDEX, 4), vec![1]),
        (
            Address::new(CYCLE_INDEX, 5),
            vec![u8::from(config.potential_master)],
        ),
        (Address::new(COUNT_INDEX, 0), vec![0]),
    ];
    for (n, entry) in config.entries.iter().enumerate() {
        let index = FIRST_ENTRY_INDEX + n as u16;
        writes.extend([
            (Address::new(index, 1), vec![entry.sc_id]),
            (Address::new(index, 2), vec![entry.role]),
            (Address::new(index, 3), entry.slot.to_le_bytes().to_vec()),
            (
                Address::new(index, 4),
                entry.timeout_ms.to_le_bytes().to_vec(),
            ),
            (
                Address::new(index, 5),
                node_hash(entry.sc_id).to_le_bytes().to_vec(),
            ),
            (Address::new(index, 6), entry.mapped.to_le_bytes().to_vec()),
        ]);
    }
    writes.push((
        Address::new(COUNT_INDEX, 0),
        vec![config.entries.len() as u8],
    ));
    for (address, data) in &writes {
        sdo_write(net, id, *address, data)
            .map_err(|e| fail(&format!("{:04X}h:{:02X}", address.index, address.sub), e))?;
    }
    let mut fed = vec![id];
    for (address, data) in writes.iter().filter(|(a, _)| a.index != COUNT_INDEX) {
        let back = sdo_read(net, id, *address).map_err(|e| fail("reading back", e))?;
        if &back != data {
            return Err(format!(
                "node {id}: {:04X}h:{:02X} reads back {back:02X?}, {data:02X?} was written",
                address.index, address.sub
            ));
        }
        fed.extend(&back);
        if address.index == CYCLE_INDEX && address.sub == 5 {
            fed.push(config.entries.len() as u8);
        }
    }
    let signature = crc32_mpeg2(&fed);
    sdo_write(
        net,
        id,
        Address::new(SIGNATURE_INDEX, 0),
        &signature.to_le_bytes(),
    )
    .map_err(|e| fail("5EFFh", e))?;
    sdo_write(net, id, Address::new(VALID_INDEX, 0), &[0xA5]).map_err(|e| fail("5EFEh", e))?;
    sdo_write(net, id, Address::new(0x1010, 1), b"save").map_err(|e| fail("1010h", e))?;
    Ok(())
}

fn sdo_write(
    net: &mut impl Simulation,
    id: u8,
    address: Address,
    data: &[u8],
) -> Result<(), ClientError> {
    client(net).write(id, address, data).map_err(sdo_error)
}

fn sdo_read(net: &mut impl Simulation, id: u8, address: Address) -> Result<Vec<u8>, ClientError> {
    client(net).read(id, address).map_err(sdo_error)
}

impl Simulation for ScNetwork {
    fn now(&self) -> Instant {
        self.now
    }
    fn tool_send(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }
    fn traced(&self, index: usize) -> Option<CanFrame> {
        self.trace.get(index).map(|(_, _, frame, _)| *frame)
    }
    fn traced_count(&self) -> usize {
        self.trace.len()
    }
    fn run_until(&mut self, end: Instant) {
        ScNetwork::run_until(self, end);
    }
}
