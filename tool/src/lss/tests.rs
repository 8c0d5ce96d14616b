//! Tests of the LSS master against the node's LSS slave (`shared::canopen::lss`) and whole
//! devices, over a simulated bus in simulated time; each names the figure of CiA 305 or the
//! rule it verifies.

use super::*;
use crate::calc::bus::frame_micros;
use crate::network_file;
use shared::canopen::NodeId;
use shared::canopen::lss::{BitRates, Lss, LssState};
use shared::canopen::storage::RamFlash;
use shared::node::{Event, Node, Sink};
use shared::{CanId, Instant};
use std::collections::VecDeque;

const BIT_RATE: u32 = 500_000;
const RATES: BitRates = BitRates::of(&[BitRate::Kbit500, BitRate::Kbit250, BitRate::Kbit125]);
const TIMEOUT: Duration = Duration::from_millis(10);

type Device = Node<RamFlash<8192>, 4>;

/// A node on the simulated bus: the LSS slave alone, or a whole device.
enum Slave {
    Lss(Lss),
    Device(Box<Device>),
}

/// A sink that keeps the frames a device sends.
#[derive(Default)]
struct Frames(Vec<CanFrame>, Vec<Event>);

impl Sink for Frames {
    fn transmit(&mut self, frame: CanFrame) {
        self.0.push(frame);
    }
    fn event(&mut self, event: Event) {
        self.1.push(event);
    }
}

/// A bus of slaves in simulated time: a frame occupies the bus for its worst-case time at
/// [`BIT_RATE`]; answers follow the request one after the other.
struct Bus {
    now: Duration,
    slaves: Vec<Slave>,
    queue: VecDeque<(Duration, CanFrame)>,
    /// Every frame that was on the bus (requests and answers).
    frames: u64,
}

impl Bus {
    fn new(slaves: Vec<Slave>) -> Self {
        Bus {
            now: Duration::ZERO,
            slaves,
            queue: VecDeque::new(),
            frames: 0,
        }
    }

    fn frame_time() -> Duration {
        Duration::from_micros(frame_micros(8, BIT_RATE))
    }

    fn lss(&self, index: usize) -> &Lss {
        match &self.slaves[index] {
            Slave::Lss(lss) => lss,
            Slave::Device(device) => device.lss().unwrap(),
        }
    }
}

impl Transport for Bus {
    fn now(&mut self) -> Duration {
        self.now
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.frames += 1;
        let mut at = self.now + Bus::frame_time();
        let instant = Instant::from_micros(at.as_micros() as u64);
        let mut sent = Vec::new();
        for slave in &mut self.slaves {
            match slave {
                Slave::Lss(lss) => {
                    let outcome = lss.on_frame(instant, frame, false, |_| Ok(()));
                    sent.extend(outcome.response);
                    if outcome.reset_communication {
                        if let Some(id) = lss.reset_communication() {
                            let boot_up = CanId::new(0x700 + u16::from(id.raw())).unwrap();
                            sent.push(CanFrame::new(boot_up, &[0]).unwrap());
                        }
                    }
                }
                Slave::Device(device) => {
                    let mut sink = Frames::default();
                    device.handle_frame(instant, frame, &mut sink);
                    sent.extend(sink.0);
                }
            }
        }
        for answer in sent {
            at += Bus::frame_time();
            self.frames += 1;
            self.queue.push_back((at, answer));
        }
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        match self.queue.front() {
            Some(&(at, frame)) if at <= deadline => {
                self.queue.pop_front();
                self.now = self.now.max(at);
                Ok(Some(frame))
            }
            _ => {
                self.now = self.now.max(deadline);
                Ok(None)
            }
        }
    }
}

fn unconfigured(identity: [u32; 4]) -> Slave {
    Slave::Lss(Lss::new(identity, None, None, RATES))
}

/// A whole device with LSS enabled on `flash`, its switches open, polled once: with the
/// frames it sent.
fn device(identity: [u32; 4], flash: RamFlash<8192>) -> (Device, Vec<CanFrame>) {
    let mut config = safety_device::config(NodeId::new(1).unwrap(), "LSS test node");
    config.identity = identity;
    let mut device = Device::new(config, flash).unwrap();
    assert!(device.enable_lss(None, RATES));
    let mut sink = Frames::default();
    let _ = device.poll(Instant::ZERO, &mut sink);
    (device, sink.0)
}

/// A network file of nodes `(node-ID, identity)`; a revision of `None` is left unpinned.
fn network(nodes: &[(u8, [u32; 4], bool)]) -> Network {
    let mut text = String::new();
    for (id, [vendor, product, revision, serial], pinned) in nodes {
        text.push_str(&format!("[[node]]\nid = {id}\nname = \"node {id}\"\n"));
        if *pinned {
            text.push_str(&format!(
                "identity = {{ vendor = {vendor}, product = {product}, revision = {revision}, serial = {serial} }}\n"
            ));
        } else {
            text.push_str(&format!(
                "identity = {{ vendor = {vendor}, product = {product}, serial = {serial} }}\n"
            ));
        }
    }
    network_file::parse(&text, "lss.toml").unwrap()
}

/// The figures of one fastscan: frames on the bus against their bus-time floor (every frame
/// 8 data bytes without a stuff bit: 47 + 64 bits, ISO 11898-1) and the simulated time the
/// timeouts make it take.
fn print_figures(what: &str, nodes: usize, bus: &Bus, report: &FastscanReport) {
    let floor_us = bus.frames * (47 + 64) * 1_000_000 / u64::from(BIT_RATE);
    let worst_us = bus.frames * frame_micros(8, BIT_RATE);
    println!(
        "{what}: {nodes} unconfigured nodes: {} requests, {} answers, {} frames on the bus (with boot-up messages); \
         bus-time floor at {} kbit/s {floor_us} us (worst case with stuff bits {worst_us} us); \
         simulated time with a {} ms answer window {} ms",
        report.requests,
        report.answers,
        bus.frames,
        BIT_RATE / 1000,
        TIMEOUT.as_millis(),
        bus.now.as_millis()
    );
}

const VENDOR: u32 = 0x0000_0ABC;
const PRODUCT: u32 = 0x0000_0304;

#[test]
fn cia305_fig46_fastscan_gives_one_unconfigured_node_the_file_s_node_id() {
    let identity = [VENDOR, PRODUCT, 0x0001_0002, 0x8000_0042];
    let mut master = LssMaster::new(Bus::new(vec![unconfigured(identity)]), TIMEOUT);
    let file = network(&[(5, identity, true)]);
    let report = master.fastscan_assign(&file, true).unwrap();
    assert_eq!(
        report.assigned,
        [Assigned {
            identity: super::identity(identity),
            node_id: 5,
            name: Some("node 5".into()),
            stored: true,
        }]
    );
    assert!(report.unknown.is_empty() && report.duplicates.is_empty());
    let lss = master.transport.lss(0);
    assert_eq!(lss.active().map(NodeId::raw), Some(5));
    assert_eq!(lss.state(), LssState::Waiting);
    // The file names its whole identity: 1 reset (is anyone unconfigured?), the 4 requests of
    // the selection, inquire node-ID; node-ID, store, switch; then one reset nobody answers:
    // no unconfigured node is left. No bit is scanned.
    assert_eq!(report.requests, 1 + 4 + 1 + 3 + 1);
    assert_eq!(report.answers, 1 + 1 + 1 + 2);
    print_figures("fastscan", 1, &master.transport, &report);
}

#[test]
fn cia305_fig46_fastscan_finds_eight_nodes_in_identity_order_and_reports_the_unknown_one() {
    // One vendor and product; revisions and serial numbers that share long prefixes, and one
    // node (serial 7) the file does not know, in the middle of the order.
    let identities: Vec<[u32; 4]> = [
        (1, 1),
        (1, 2),
        (1, 3),
        (2, 1),
        (1, 7),
        (1, 0x8000_0000),
        (0x0100_0000, 5),
        (1, 0xFFFF_FFFF),
    ]
    .into_iter()
    .map(|(revision, serial)| [VENDOR, PRODUCT, revision, serial])
    .collect();
    let known: Vec<(u8, [u32; 4], bool)> = identities
        .iter()
        .enumerate()
        .filter(|(_, identity)| identity[3] != 7)
        .map(|(index, identity)| (10 + index as u8, *identity, true))
        .collect();
    let slaves = identities
        .iter()
        .map(|&identity| unconfigured(identity))
        .collect();
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    let report = master.fastscan_assign(&network(&known), false).unwrap();
    let mut order = identities.clone();
    order.sort();
    let expected: Vec<(NodeIdentity, u8)> = known
        .iter()
        .map(|(id, identity, _)| (super::identity(*identity), *id))
        .collect();
    let mut got: Vec<(NodeIdentity, u8)> = report
        .assigned
        .iter()
        .map(|assigned| (assigned.identity, assigned.node_id))
        .collect();
    // Found in identity order.
    let found_order: Vec<[u32; 4]> = report.assigned.iter().map(|a| parts(a.identity)).collect();
    let mut sorted = found_order.clone();
    sorted.sort();
    assert_eq!(found_order, sorted);
    got.sort_by_key(|(_, id)| *id);
    assert_eq!(got, expected);
    assert_eq!(report.unknown, [super::identity([VENDOR, PRODUCT, 1, 7])]);
    for (index, identity) in identities.iter().enumerate() {
        let active = master.transport.lss(index).active().map(NodeId::raw);
        let wanted = known.iter().find(|k| k.1 == *identity).map(|k| k.0);
        assert_eq!(active, wanted, "{identity:X?}");
    }
    print_figures("fastscan", 8, &master.transport, &report);
}

#[test]
fn cia305_fig46_fastscan_with_no_unconfigured_node_finds_nothing_in_one_request() {
    let configured = Lss::new(
        [VENDOR, PRODUCT, 1, 1],
        None,
        Some(shared::canopen::lss::LssSettings {
            node_id: NodeId::new(3).ok(),
            bit_rate: None,
        }),
        RATES,
    );
    let mut master = LssMaster::new(Bus::new(vec![Slave::Lss(configured)]), TIMEOUT);
    let report = master
        .fastscan_assign(&network(&[(3, [VENDOR, PRODUCT, 1, 1], true)]), true)
        .unwrap();
    assert_eq!(
        report,
        FastscanReport {
            requests: 1,
            ..FastscanReport::default()
        }
    );
}

#[test]
fn cia305_fig46_two_nodes_matching_one_file_entry_the_second_is_reported() {
    let first = [VENDOR, PRODUCT, 1, 9];
    let second = [VENDOR, PRODUCT, 2, 9];
    let slaves = vec![unconfigured(second), unconfigured(first)];
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    let report = master
        .fastscan_assign(&network(&[(4, first, false)]), false)
        .unwrap();
    assert_eq!(report.assigned.len(), 1);
    assert_eq!(report.assigned[0].identity, super::identity(first));
    assert_eq!(report.duplicates, [(super::identity(second), 4)]);
    assert_eq!(master.transport.lss(0).active(), None, "left unconfigured");
}

/// End to end: fastscan gives a whole device its node-ID and stores it; the device boots on
/// it at once, and again after a power cycle.
#[test]
fn cia305_fig36_fastscan_stores_the_node_id_of_a_whole_device() {
    let identity = [VENDOR, PRODUCT, 1, 77];
    let (fresh, sent) = device(identity, RamFlash::new());
    assert!(
        sent.is_empty(),
        "an unconfigured device sends nothing: {sent:?}"
    );
    let slaves = vec![Slave::Device(Box::new(fresh))];
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    let report = master
        .fastscan_assign(&network(&[(21, identity, true)]), true)
        .unwrap();
    assert_eq!(report.assigned.len(), 1);
    let Slave::Device(device) = &master.transport.slaves[0] else {
        unreachable!()
    };
    assert_eq!(device.configured_node_id().map(NodeId::raw), Some(21));
    let (powered_again, sent) = self::device(identity, device.flash().clone());
    assert_eq!(
        powered_again.configured_node_id().map(NodeId::raw),
        Some(21)
    );
    assert_eq!(
        sent.first()
            .map(|frame| (frame.id().raw(), frame.data().to_vec())),
        Some((0x715, vec![0]))
    );
    // Inquire it by its identity: node-ID 21 active.
    let slaves = vec![Slave::Device(Box::new(powered_again))];
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    master.select(super::identity(identity)).unwrap();
    let target = Target::Node(super::identity(identity));
    assert_eq!(master.inquire_node_id(target).unwrap(), Some(21));
    assert_eq!(
        master.inquire_identity(target).unwrap(),
        super::identity(identity)
    );
}

#[test]
fn cia305_fig32_a_missing_node_is_named_by_its_identity_and_the_step() {
    let mut master = LssMaster::new(
        Bus::new(vec![unconfigured([VENDOR, PRODUCT, 1, 1])]),
        TIMEOUT,
    );
    let absent = super::identity([VENDOR, PRODUCT, 1, 2]);
    let error = master.select(absent).unwrap_err();
    assert_eq!(
        error.to_string(),
        "the node with vendor 00000ABCh, product 00000304h, revision 00000001h, serial 2: \
         switch state selective: no LSS answer within 10 ms (is the node on the bus, at this \
         bit rate, in NMT Pre-operational or Stopped, and is its identity right?)"
    );
}

#[test]
fn cia305_fig33_a_node_with_its_switches_set_refuses_a_node_id_in_words() {
    let identity = [VENDOR, PRODUCT, 1, 1];
    let switched = Lss::new(identity, NodeId::new(3).ok(), None, RATES);
    let mut master = LssMaster::new(Bus::new(vec![Slave::Lss(switched)]), TIMEOUT);
    master.select(super::identity(identity)).unwrap();
    let target = Target::Node(super::identity(identity));
    let error = master.configure_node_id(target, Some(9)).unwrap_err();
    let text = error.to_string();
    assert!(text.starts_with("the node with vendor 00000ABCh"), "{text}");
    assert!(
        text.contains("configure node-ID: the node refused with error code FFh"),
        "{text}"
    );
    assert!(text.contains("switches are set"), "{text}");
    // The tool refuses a node-ID outside 1..=127 before sending anything.
    let sent = master.requests;
    for bad in [0u8, 0x80, 0xFE] {
        assert!(matches!(
            master.configure_node_id(target, Some(bad)),
            Err(LssError::Usage(_))
        ));
    }
    assert_eq!(master.requests, sent);
}

#[test]
fn cia305_fig34_a_bit_rate_the_node_does_not_support_is_refused_in_words() {
    let identity = [VENDOR, PRODUCT, 1, 1];
    let mut master = LssMaster::new(Bus::new(vec![unconfigured(identity)]), TIMEOUT);
    master.select(super::identity(identity)).unwrap();
    let target = Target::Node(super::identity(identity));
    master.configure_bit_rate(target, BitRate::Kbit250).unwrap();
    let error = master
        .configure_bit_rate(target, BitRate::Kbit1000)
        .unwrap_err();
    assert!(error.to_string().contains("configure bit timing: the node refused with error code 01h: the bit rate is not in the CiA 301 table or the node does not support it"), "{error}");
    assert_eq!(master.transport.lss(0).bit_rate(), Some(BitRate::Kbit250));
}

#[test]
fn cia305_an_inquiry_answered_by_two_nodes_is_refused_as_ambiguous() {
    let slaves = vec![
        unconfigured([VENDOR, PRODUCT, 1, 1]),
        unconfigured([VENDOR, PRODUCT, 1, 2]),
    ];
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    master.switch_global(true).unwrap();
    let error = master.inquire_node_id(Target::Selected).unwrap_err();
    assert_eq!(
        error.to_string(),
        "the node in LSS configuration state: inquire node-ID: 2 nodes answered; LSS without \
         an identity needs exactly one LSS node in the configuration state (name the node's \
         identity)"
    );
}

#[test]
fn an_identity_on_the_command_line_is_four_numbers() {
    assert_eq!(
        parse_identity("0xABC:772:0x10002:42").unwrap(),
        super::identity([0xABC, 772, 0x1_0002, 42])
    );
    for bad in [
        "",
        "1:2:3",
        "1:2:3:4:5",
        "1:2:x:4",
        "1:2:3:4294967296",
        "0xG:1:1:1",
    ] {
        let error = parse_identity(bad).unwrap_err().to_string();
        assert!(
            error.contains("is not an identity VENDOR:PRODUCT:REVISION:SERIAL"),
            "{error}"
        );
    }
}

#[test]
fn the_lss_command_reports_assigned_and_unknown_nodes_and_fails_with_unknown_ones() {
    let known = [VENDOR, PRODUCT, 1, 1];
    let stranger = [VENDOR, PRODUCT, 1, 2];
    let bus = Bus::new(vec![unconfigured(known), unconfigured(stranger)]);
    let command = LssCommand::Fastscan {
        file: "lss.toml".into(),
        store: true,
    };
    let file = network(&[(6, known, true)]);
    let output = run(bus, &command, Some(&file), TIMEOUT).unwrap();
    assert!(!output.complete, "a node was left unconfigured");
    let lines: Vec<&str> = output.text.lines().collect();
    assert_eq!(
        lines[..2],
        [
            "node 6 (node 6): vendor 00000ABCh, product 00000304h, revision 00000001h, serial 1 given node-ID 6, stored; it booted on it",
            "not in the network file, left unconfigured: vendor 00000ABCh, product 00000304h, revision 00000001h, serial 2",
        ]
    );
    assert_eq!(output.json["assigned"][0]["node_id"], 6);
    assert_eq!(output.json["unknown"][0]["serial"], 2);
}

#[test]
fn the_lss_command_refuses_bad_arguments_before_sending() {
    let identity = "0xABC:0x304:1:1".to_owned();
    for (command, words) in [
        (
            LssCommand::SetId {
                identity: identity.clone(),
                node_id: "128".into(),
                store: false,
            },
            "\"128\" is not a node-ID 1 to 127, nor `none`",
        ),
        (
            LssCommand::SetBitrate {
                identity: identity.clone(),
                bit_rate: 100_000,
                store: false,
            },
            "100000 bit/s is not in the CiA 301 bit-timing table",
        ),
        (
            LssCommand::Store {
                identity: "0xABC:0x304:1".into(),
            },
            "is not an identity",
        ),
    ] {
        let mut bus = Bus::new(vec![unconfigured([VENDOR, PRODUCT, 1, 1])]);
        let error = run(&mut bus, &command, None, TIMEOUT)
            .unwrap_err()
            .to_string();
        assert!(error.contains(words), "{error}");
        assert_eq!(bus.frames, 0, "nothing sent");
    }
}

#[test]
fn the_lss_command_sets_a_node_id_by_identity_and_inquires_the_only_node() {
    let identity = [VENDOR, PRODUCT, 1, 1];
    let mut bus = Bus::new(vec![unconfigured(identity)]);
    let set = LssCommand::SetId {
        identity: "0xABC:0x304:1:1".into(),
        node_id: "33".into(),
        store: true,
    };
    let output = run(&mut bus, &set, None, TIMEOUT).unwrap();
    assert!(
        output.text.contains("node-ID 33 pending, stored"),
        "{}",
        output.text
    );
    // It was unconfigured: it took the node-ID when switched back to waiting.
    assert_eq!(bus.lss(0).active().map(NodeId::raw), Some(33));
    let output = run(
        &mut bus,
        &LssCommand::Inquire { identity: None },
        None,
        TIMEOUT,
    )
    .unwrap();
    assert_eq!(
        output.text,
        "vendor 00000ABCh, product 00000304h, revision 00000001h, serial 1: active node-ID 33\n"
    );
    assert_eq!(
        bus.lss(0).state(),
        LssState::Waiting,
        "left in the waiting state"
    );
}

/// A node the file names whose node-ID is set already is selected, asked, and left alone
/// (Fig. 41: it answers its active node-ID); the unconfigured one beside it gets its node-ID,
/// and the named node that is absent costs only its selection.
#[test]
fn cia305_fig41_fastscan_leaves_a_configured_node_it_selects_by_identity_alone() {
    let configured = Lss::new(
        [VENDOR, PRODUCT, 1, 1],
        None,
        Some(shared::canopen::lss::LssSettings {
            node_id: NodeId::new(3).ok(),
            bit_rate: None,
        }),
        RATES,
    );
    let fresh = [VENDOR, PRODUCT, 1, 2];
    let slaves = vec![Slave::Lss(configured), unconfigured(fresh)];
    let mut master = LssMaster::new(Bus::new(slaves), TIMEOUT);
    let file = network(&[
        (9, [VENDOR, PRODUCT, 1, 1], true),
        (10, fresh, true),
        (11, [VENDOR, PRODUCT, 1, 0], true),
    ]);
    let report = master.fastscan_assign(&file, false).unwrap();
    assert_eq!(report.assigned.len(), 1);
    assert_eq!(
        (report.assigned[0].identity, report.assigned[0].node_id),
        (super::identity(fresh), 10)
    );
    assert!(report.unknown.is_empty() && report.duplicates.is_empty());
    let [kept, given] = [0, 1].map(|index| master.transport.lss(index));
    assert_eq!(kept.active().map(NodeId::raw), Some(3));
    assert_eq!(kept.pending().map(NodeId::raw), Some(3), "nothing pending");
    assert_eq!(kept.state(), LssState::Waiting);
    assert_eq!(given.active().map(NodeId::raw), Some(10));
}
