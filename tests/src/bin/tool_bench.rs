//! The configuration tool's speed benchmark (`cargo xtask bench` appends its output to
//! docs/performance.md): configure, read back, sign, validate and store one node with 16
//! transmit SRDOs, then verify it, on the host simulation at 500 kbit/s under simulated
//! time; SDO transactions, frames and bus time against the floor, the bus time of the
//! procedure's own SDO frames sent back to back. Deterministic: the same figures every run.

use safety_config::client::Client;
use safety_config::network_file;
use safety_config::procedure::{self, NodeResult, Quiet, Verdict};
use shared::canopen::NodeId;
use shared::canopen::storage::RamFlash;
use shared::node::{Event, Node, Sink};
use shared::{CanFrame, Duration, Instant};
use std::fmt::Write as _;
use std::process::ExitCode;
use system_tests::bus::{Bus, Delivery, frame_time};
use system_tests::tool_bus::{SimulatedBus, Simulation};

/// SRDOs of the benchmarked node.
const SRDOS: usize = 16;
/// Bit rate.
const BIT_RATE: u32 = 500_000;
/// The node's ID (a producer by the pre-defined connection set).
const NODE: u8 = 1;

type BenchNode = Node<RamFlash<8192>, SRDOS>;

#[derive(Default)]
struct Outbox(Vec<CanFrame>);

impl Sink for Outbox {
    fn transmit(&mut self, frame: CanFrame) {
        self.0.push(frame);
    }
    fn event(&mut self, _event: Event) {}
}

/// One node with 16 SRDOs and the tool (participant 0) on a simulated bus.
struct OneNode {
    now: Instant,
    bus: Bus,
    node: BenchNode,
    deadline: Instant,
    in_flight: Vec<Delivery>,
    trace: Vec<(Instant, CanFrame, usize)>,
}

impl OneNode {
    fn new() -> Result<Self, String> {
        let id = NodeId::new(NODE).map_err(|_| "node-ID".to_owned())?;
        let config = safety_device::config(id, safety_device::CHANNEL_A_NAME);
        let node = BenchNode::new(config, RamFlash::new())
            .map_err(|error| format!("the node refused its description: {error:?}"))?;
        Ok(OneNode {
            now: Instant::ZERO,
            bus: Bus::new(BIT_RATE, 2),
            node,
            deadline: Instant::ZERO,
            in_flight: Vec::new(),
            trace: Vec::new(),
        })
    }

    fn step(&mut self) {
        let now = self.now;
        let (due, later): (Vec<_>, Vec<_>) = self.in_flight.drain(..).partition(|d| d.at <= now);
        self.in_flight = later;
        let mut outbox = Outbox::default();
        for delivery in due {
            self.trace
                .push((delivery.at, delivery.frame, delivery.from));
            if delivery.from != 1 {
                self.node.handle_frame(now, &delivery.frame, &mut outbox);
            }
        }
        self.deadline = self.node.poll(now, &mut outbox);
        for frame in outbox.0 {
            self.bus.send(1, frame);
        }
        if self.bus.next_start(now) == Some(now) {
            let deliveries = self.bus.arbitrate(now);
            self.in_flight.extend(deliveries);
        }
    }
}

impl Simulation for OneNode {
    fn now(&self) -> Instant {
        self.now
    }
    fn tool_send(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }
    fn traced(&self, index: usize) -> Option<CanFrame> {
        self.trace.get(index).map(|(_, frame, _)| *frame)
    }
    fn traced_count(&self) -> usize {
        self.trace.len()
    }
    fn run_until(&mut self, end: Instant) {
        loop {
            let next = self
                .in_flight
                .iter()
                .map(|d| d.at)
                .chain([self.deadline])
                .chain(self.bus.next_start(self.now))
                .min()
                .unwrap_or(Instant::NEVER);
            if next > end {
                self.now = self.now.max(end);
                return;
            }
            self.now = self.now.max(next);
            self.step();
        }
    }
}

/// The network file: 16 transmit SRDOs on 101h/102h .. 11Fh/120h, each mapping the input and
/// its inverted copy.
fn file() -> String {
    let mut text = String::from(
        "[[node]]\nid = 1\nidentity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }\n",
    );
    for n in 1..=SRDOS {
        let plain = 0xFF + 2 * n;
        let _ = write!(
            text,
            "\n[[node.srdo]]\nnumber = {n}\ndirection = \"transmit\"\nrefresh_time_ms = 100\n\
             srvt_ms = 20\ncob_ids = [0x{plain:X}, 0x{:X}]\nmapping = [\"input\", \"input_inverted\"]\n",
            plain + 1
        );
    }
    text
}

/// What one step of the procedure cost.
struct Cost {
    transactions: u64,
    frames: usize,
    bus_time: Duration,
    elapsed: Duration,
    floor: Duration,
}

/// Frames, bus time and floor of `trace[from..]` (`sdo`: the node's SDO identifiers and NMT).
fn measure(
    trace: &[(Instant, CanFrame, usize)],
    from: usize,
    transactions: u64,
    elapsed: Duration,
) -> Cost {
    let frames = &trace[from..];
    let bus_time: u64 = frames
        .iter()
        .map(|(_, frame, _)| frame_time(frame, BIT_RATE).as_micros())
        .sum();
    let own = |frame: &CanFrame| {
        let id = frame.id().raw();
        id == 0x600 + u16::from(NODE) || id == 0x580 + u16::from(NODE) || id == 0x000
    };
    let floor: u64 = frames
        .iter()
        .filter(|(_, frame, _)| own(frame))
        .map(|(_, frame, _)| frame_time(frame, BIT_RATE).as_micros())
        .sum();
    Cost {
        transactions,
        frames: frames.len(),
        bus_time: Duration::from_micros(bus_time),
        elapsed,
        floor: Duration::from_micros(floor),
    }
}

fn ms(duration: Duration) -> String {
    format!("{:.1} ms", duration.as_micros() as f64 / 1000.0)
}

fn main() -> ExitCode {
    match run() {
        Ok(report) => {
            print!("{report}");
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("tool-bench: {error}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<String, String> {
    let network = network_file::parse(&file(), "benchmark").map_err(|e| e.to_string())?;
    let mut net = OneNode::new()?;
    net.run_until(Instant::from_micros(50_000));
    let mut client = Client::new(
        SimulatedBus::new(net),
        std::time::Duration::from_millis(500),
    );
    let mut quiet = Quiet {
        accept_identity: false,
    };

    let start = client.transport.net.now;
    let first = client.transport.net.trace.len();
    let report = procedure::configure(&mut client, &network, false, &mut quiet)
        .map_err(|e| e.to_string())?;
    if let Some(NodeResult::Failed { error, .. }) = report.nodes.first() {
        return Err(format!("configure failed: {error}"));
    }
    // The last response is in the trace once the client has it; frames after it are not the
    // procedure's.
    let configured = client.transport.net.now;
    let configure_cost = measure(
        &client.transport.net.trace,
        first,
        client.requests,
        configured.saturating_since(start),
    );

    let before = client.requests;
    let second = client.transport.net.trace.len();
    let verdicts = procedure::verify(&mut client, &network).map_err(|e| e.to_string())?;
    if verdicts != [Verdict::Matches { node: NODE }] {
        return Err(format!("verify: {verdicts:?}"));
    }
    let verify_cost = measure(
        &client.transport.net.trace,
        second,
        client.requests - before,
        client.transport.net.now.saturating_since(configured),
    );
    let total = measure(
        &client.transport.net.trace,
        first,
        client.requests,
        client.transport.net.now.saturating_since(start),
    );
    if client
        .transport
        .net
        .node
        .safety_config()
        .configuration_valid
        != shared::safety::config::CONFIGURATION_VALID
    {
        return Err("the node is not validated after configure".into());
    }

    let mut md = String::new();
    let _ = writeln!(
        md,
        "\n## Configuration tool: one node with {SRDOS} SRDOs\n\n\
         Generated by `cargo xtask bench` (`cargo run --release -p system-tests --bin tool_bench`): \
         `safety-config`'s `configure` (identity, NMT pre-operational, every SRDO deleted, \
         mapping and communication parameters written, every record read back and compared, \
         signatures written and read back, 0x13FE, store, 0x13FE again; EN 50325-5 8.3.1) and \
         `verify` (identity, 0x13FE, every record and signature read) of one node with {SRDOS} \
         transmit SRDOs, on the host simulation at {} kbit/s under simulated time, so the \
         figures repeat exactly. *Bus time* is the time the bus carried frames (the node's \
         heartbeats included); the *floor* is the bus time of the procedure's own frames (its \
         SDO requests, the node's answers and the NMT command) sent back to back, which no \
         tool doing these transfers can go below; *elapsed* is simulated time from the first \
         request to the last answer, with the simulated tool looking for answers every 100 µs.\n",
        BIT_RATE / 1000
    );
    let _ = writeln!(
        md,
        "| step | SDO transactions | frames | bus time | floor | elapsed | elapsed / floor |"
    );
    let _ = writeln!(
        md,
        "|------|-----------------:|-------:|---------:|------:|--------:|----------------:|"
    );
    for (step, cost) in [
        ("configure", &configure_cost),
        ("verify", &verify_cost),
        ("both", &total),
    ] {
        let _ = writeln!(
            md,
            "| {step} | {} | {} | {} | {} | {} | {:.2} |",
            cost.transactions,
            cost.frames,
            ms(cost.bus_time),
            ms(cost.floor),
            ms(cost.elapsed),
            cost.elapsed.as_micros() as f64 / cost.floor.as_micros().max(1) as f64
        );
    }
    Ok(md)
}
