//! Configuring and verifying a node's SimpleCAN objects (docs/simplecan.md section 11;
//! SC_REQ_35, SC_REQ_36): the plan for a given network file, operation by operation, and its
//! execution against a small in-memory node that follows section 11's contract (any accepted
//! write to 5E00h..5E5Fh sets 5EFEh to 0; 5EFEh takes A5h only when 5EFFh is the signature of
//! what it holds, computed with the `crc` crate as the device does).

use safety_config::client::Client;
use safety_config::network_file::parse;
use safety_config::procedure::{self, NodeResult, Quiet, Verdict};
use safety_config::simplecan::plan::{Operation, configure_plan};
use safety_config::simplecan::{self, node_config};
use safety_config::transport::{Transport, TransportError};
use shared::canopen::od::Address;
use shared::{CanFrame, CanId};
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

const FILE: &str = r#"[simplecan]
network_name = "press line 3"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 500

[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, serial = 1 }
[node.simplecan]
potential_master = true
produce = [{ sc_id = 0x30, slot = 0, object = "input" }]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[node.simplecan]
consume = [{ sc_id = 0x30, timeout_ms = 50, object = "output" }]
"#;

fn write(index: u16, sub: u8, data: &[u8]) -> Operation {
    Operation::Write {
        address: Address::new(index, sub),
        data: data.to_vec(),
    }
}

fn read(index: u16, sub: u8, len: usize) -> Operation {
    Operation::ReadBack {
        address: Address::new(index, sub),
        len,
    }
}

/// Node 33's plan, every operation in order: the writes of section 11's order, the read-back
/// in the reverse order, the comparison, the signature, 5EFEh, the store.
#[test]
fn sc_req_35_and_sc_req_36_the_plan_for_a_consumer_operation_by_operation() {
    let network = parse(FILE, "net.toml").unwrap();
    let simplecan = network.simplecan.as_ref().unwrap();
    let hash = simplecan.hashes[&0x30].to_le_bytes();
    let config = node_config(simplecan, 33);
    let signature = simplecan::signature::signature(&config);
    let expected = vec![
        write(0x5E01, 0, &[0]),
        write(0x5E00, 1, &[10, 0]),
        write(0x5E00, 2, &[10, 0]),
        write(0x5E00, 3, &[0xF4, 0x01]),
        write(0x5E00, 4, &[1]),
        write(0x5E00, 5, &[0]),
        write(0x5E10, 1, &[0x30]),
        write(0x5E10, 2, &[2]),
        write(0x5E10, 3, &[0, 0]),
        write(0x5E10, 4, &[50, 0]),
        write(0x5E10, 5, &hash),
        write(0x5E10, 6, &[0x08, 0x01, 0x00, 0x62]),
        write(0x5E01, 0, &[1]),
        read(0x5E10, 6, 4),
        read(0x5E10, 5, 4),
        read(0x5E10, 4, 2),
        read(0x5E10, 3, 2),
        read(0x5E10, 2, 1),
        read(0x5E10, 1, 1),
        read(0x5E01, 0, 1),
        read(0x5E00, 5, 1),
        read(0x5E00, 4, 1),
        read(0x5E00, 3, 2),
        read(0x5E00, 2, 2),
        read(0x5E00, 1, 2),
        Operation::Compare,
        write(0x5EFF, 0, &signature.to_le_bytes()),
        Operation::Expect {
            address: Address::new(0x5EFF, 0),
            len: 4,
            value: signature,
        },
        write(0x5EFE, 0, &[0xA5]),
        Operation::Expect {
            address: Address::new(0x5EFE, 0),
            len: 1,
            value: 0xA5,
        },
        write(0x1010, 1, b"save"),
        Operation::Expect {
            address: Address::new(0x5EFE, 0),
            len: 1,
            value: 0xA5,
        },
    ];
    assert_eq!(configure_plan(&config), expected);
}

/// The master's plan holds its produced entry (role 1, slot 0, 6000h:01 8 bits) and sets
/// 5E00h:05 = 1.
#[test]
fn sc_req_35_the_plan_for_a_potential_master() {
    let network = parse(FILE, "net.toml").unwrap();
    let config = node_config(network.simplecan.as_ref().unwrap(), 1);
    let plan = configure_plan(&config);
    assert!(plan.contains(&write(0x5E00, 5, &[1])));
    assert!(plan.contains(&write(0x5E10, 2, &[1])));
    assert!(plan.contains(&write(0x5E10, 6, &[0x08, 0x01, 0x00, 0x60])));
    assert_eq!(plan.len(), 13 + 12 + 1 + 6);
}

/// An in-memory node at one node-ID: expedited SDO, identity, SRDO count 0, the SimpleCAN
/// objects of section 11, and faults to inject.
struct FakeNode {
    id: u8,
    objects: BTreeMap<Address, Vec<u8>>,
    replies: VecDeque<CanFrame>,
    now: Duration,
    /// Every SDO operation received, in order: (write?, address).
    log: Vec<(bool, Address)>,
    /// A write to this address is kept with this value instead.
    corrupt: Option<(Address, Vec<u8>)>,
    stores: u32,
}

impl FakeNode {
    fn new(id: u8, serial: u32) -> FakeNode {
        let mut objects = BTreeMap::new();
        let mut put = |index, sub, data: &[u8]| {
            objects.insert(Address::new(index, sub), data.to_vec());
        };
        put(0x1018, 1, &0xABCu32.to_le_bytes());
        put(0x1018, 2, &0x304u32.to_le_bytes());
        put(0x1018, 3, &1u32.to_le_bytes());
        put(0x1018, 4, &serial.to_le_bytes());
        put(0x13FF, 0, &[0]);
        put(0x13FE, 0, &[0]);
        for (sub, len) in [(1, 2), (2, 2), (3, 2), (4, 1), (5, 1)] {
            put(0x5E00, sub, &vec![0; len]);
        }
        put(0x5E01, 0, &[0]);
        for index in 0x5E10..=0x5E5F {
            for (sub, len) in [(1, 1), (2, 1), (3, 2), (4, 2), (5, 4), (6, 4)] {
                put(index, sub, &vec![0; len]);
            }
        }
        put(0x5EFE, 0, &[0]);
        put(0x5EFF, 0, &[0; 4]);
        put(0x1010, 1, &[0; 4]);
        FakeNode {
            id,
            objects,
            replies: VecDeque::new(),
            now: Duration::ZERO,
            log: Vec::new(),
            corrupt: None,
            stores: 0,
        }
    }

    fn value(&self, index: u16, sub: u8) -> u32 {
        let bytes = &self.objects[&Address::new(index, sub)];
        let mut raw = [0u8; 4];
        raw[..bytes.len()].copy_from_slice(bytes);
        u32::from_le_bytes(raw)
    }

    /// The signature as the device computes it: the `crc` crate over section 11's octets,
    /// read from the objects it holds.
    fn device_signature(&self) -> u32 {
        let mut octets = vec![self.id];
        for sub in 1..=5 {
            octets.extend(&self.objects[&Address::new(0x5E00, sub)]);
        }
        let count = self.value(0x5E01, 0) as u16;
        octets.push(count as u8);
        for index in 0x5E10..0x5E10 + count {
            for sub in 1..=6 {
                octets.extend(&self.objects[&Address::new(index, sub)]);
            }
        }
        crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2).checksum(&octets)
    }

    fn answer(&mut self, request: &[u8]) -> [u8; 8] {
        let address = Address::new(u16::from_le_bytes([request[1], request[2]]), request[3]);
        let abort = |code: u32| {
            let mut frame = [0x80, request[1], request[2], request[3], 0, 0, 0, 0];
            frame[4..].copy_from_slice(&code.to_le_bytes());
            frame
        };
        let Some(held) = self.objects.get(&address).cloned() else {
            return abort(0x0602_0000);
        };
        match request[0] {
            0x40 => {
                self.log.push((false, address));
                let mut frame = [0u8; 8];
                frame[0] = 0x43 | (((4 - held.len()) as u8) << 2);
                frame[1..4].copy_from_slice(&request[1..4]);
                frame[4..4 + held.len()].copy_from_slice(&held);
                frame
            }
            command if command & 0xE3 == 0x23 => {
                self.log.push((true, address));
                let len = 4 - usize::from((command >> 2) & 3);
                let mut data = request[4..4 + len].to_vec();
                if len != held.len() {
                    return abort(0x0607_0010);
                }
                if address == Address::new(0x5EFE, 0)
                    && data == [0xA5]
                    && self.value(0x5EFF, 0) != self.device_signature()
                {
                    return abort(0x0800_0020);
                }
                if let Some((at, value)) = &self.corrupt {
                    if *at == address {
                        data = value.clone();
                    }
                }
                if address == Address::new(0x1010, 1) {
                    self.stores += 1;
                } else {
                    self.objects.insert(address, data);
                }
                if (0x5E00..=0x5E5F).contains(&address.index) {
                    self.objects.insert(Address::new(0x5EFE, 0), vec![0]);
                }
                [0x60, request[1], request[2], request[3], 0, 0, 0, 0]
            }
            _ => abort(0x0504_0001),
        }
    }
}

impl Transport for FakeNode {
    fn now(&mut self) -> Duration {
        self.now
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        if frame.id().raw() == 0x600 + u16::from(self.id) {
            let reply = self.answer(frame.data());
            let id = CanId::new(0x580 + u16::from(self.id)).unwrap();
            self.replies.push_back(CanFrame::new(id, &reply).unwrap());
        }
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        self.now += Duration::from_micros(500);
        let frame = self.replies.pop_front();
        if frame.is_none() {
            self.now = self.now.max(deadline);
        }
        Ok(frame)
    }
}

fn one_node_file(id: u8) -> safety_config::network_file::Network {
    let network = parse(FILE, "net.toml").unwrap();
    let mut single = network.clone();
    single.nodes.retain(|node| node.id == id);
    single
}

/// The whole configure against the in-memory node: SRDO part (none), then the SimpleCAN
/// plan; the node takes A5h only because the tool's signature equals the device's, and
/// verify then finds it matching.
#[test]
fn sc_req_35_and_sc_req_36_configure_then_verify_a_node() {
    let file = one_node_file(33);
    let mut client = Client::new(FakeNode::new(33, 33), Duration::from_millis(100));
    let report = procedure::configure(
        &mut client,
        &file,
        false,
        &mut Quiet {
            accept_identity: false,
        },
    )
    .unwrap();
    let NodeResult::Done(done) = &report.nodes[0] else {
        panic!("{report:?}");
    };
    let node = &client.transport;
    assert_eq!(done.simplecan_signature, Some(node.device_signature()));
    assert_eq!(node.value(0x5EFE, 0), 0xA5);
    assert_eq!(node.value(0x5E01, 0), 1);
    assert_eq!(node.stores, 2, "the SRDOs' store and SimpleCAN's");
    // The SimpleCAN operations the node saw are the plan's, in its order.
    let config = node_config(file.simplecan.as_ref().unwrap(), 33);
    let planned: Vec<(bool, Address)> = configure_plan(&config)
        .iter()
        .filter_map(|operation| match operation {
            Operation::Write { address, .. } => Some((true, *address)),
            Operation::ReadBack { address, .. } | Operation::Expect { address, .. } => {
                Some((false, *address))
            }
            Operation::Compare => None,
        })
        .collect();
    let first = node
        .log
        .iter()
        .position(|(write, address)| *write && address.index == 0x5E01)
        .unwrap();
    assert_eq!(node.log[first..], planned[..]);
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    assert_eq!(verdicts, vec![Verdict::Matches { node: 33 }]);
}

/// A node that keeps another value than the one written (here the timeout) is caught by the
/// read-back before any signature is written: the error names the object with both values,
/// 5EFEh stays 0 and 5EFFh was never written.
#[test]
fn sc_req_36_a_read_back_difference_stops_before_the_signature() {
    let file = one_node_file(33);
    let mut node = FakeNode::new(33, 33);
    node.corrupt = Some((Address::new(0x5E10, 4), vec![40, 0]));
    let mut client = Client::new(node, Duration::from_millis(100));
    let report = procedure::configure(
        &mut client,
        &file,
        true,
        &mut Quiet {
            accept_identity: false,
        },
    )
    .unwrap();
    let NodeResult::Failed { error, .. } = &report.nodes[0] else {
        panic!("{report:?}");
    };
    assert!(
        error.contains("SimpleCAN SDD entry 1 safety timeout (5E10h:04h): file 32h, node 28h"),
        "{error}"
    );
    assert!(!report.started);
    let node = &client.transport;
    assert_eq!(node.value(0x5EFE, 0), 0);
    assert!(
        !node
            .log
            .iter()
            .any(|(write, address)| *write && address.index == 0x5EFF),
        "no signature written"
    );
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    let Verdict::Differs { diff, .. } = &verdicts[0] else {
        panic!("{verdicts:?}");
    };
    assert!(
        diff.iter()
            .any(|line| line.contains("safety timeout (5E10h:04h)")),
        "{diff:?}"
    );
}

/// SC_REQ_38: the identity check comes first; a node with another serial number gets no
/// SimpleCAN write at all.
#[test]
fn sc_req_38_a_node_that_is_not_the_files_gets_no_simplecan_write() {
    let file = one_node_file(33);
    let mut client = Client::new(FakeNode::new(33, 34), Duration::from_millis(100));
    let report = procedure::configure(
        &mut client,
        &file,
        false,
        &mut Quiet {
            accept_identity: false,
        },
    )
    .unwrap();
    let NodeResult::Failed { error, .. } = &report.nodes[0] else {
        panic!("{report:?}");
    };
    assert!(
        error.contains("serial number: file 21h, node 22h"),
        "{error}"
    );
    assert!(client.transport.log.iter().all(|(write, _)| !write));
}

/// A node that holds the file's values but not 5EFEh = A5h is reported as not validated for
/// SimpleCAN; one whose 5EFFh is not the signature of its values differs.
#[test]
fn sc_req_36_verify_reports_an_unvalidated_or_wrongly_signed_node() {
    let file = one_node_file(33);
    let mut client = Client::new(FakeNode::new(33, 33), Duration::from_millis(100));
    let mut quiet = Quiet {
        accept_identity: false,
    };
    procedure::configure(&mut client, &file, false, &mut quiet).unwrap();
    client
        .transport
        .objects
        .insert(Address::new(0x5EFE, 0), vec![0]);
    assert_eq!(
        procedure::verify(&mut client, &file).unwrap(),
        vec![Verdict::SimpleCanNotValidated {
            node: 33,
            configuration_valid: 0,
        }]
    );
    client
        .transport
        .objects
        .insert(Address::new(0x5EFF, 0), vec![1, 2, 3, 4]);
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    let Verdict::Differs { diff, .. } = &verdicts[0] else {
        panic!("{verdicts:?}");
    };
    assert_eq!(
        diff,
        &vec![format!(
            "SimpleCAN configuration signature (5EFFh:00h): computed from the node's values {:08X}h, node holds 04030201h",
            client.transport.device_signature()
        )]
    );
}

/// The plan's size: 12 n + 19 SDO transfers for n entries (7 + 6 n writes, 6 n + 6 reads
/// back, then 5EFFh, 5EFEh and the store with a read each); 31 for one entry, 979 for 80.
#[test]
fn sc_req_35_the_plan_takes_12_n_plus_19_sdo_transfers() {
    let network = parse(FILE, "net.toml").unwrap();
    let mut config = node_config(network.simplecan.as_ref().unwrap(), 33);
    let template = config.entries[0];
    for n in [0usize, 1, 2, 80] {
        config.entries = vec![template; n];
        let transfers = configure_plan(&config)
            .iter()
            .filter(|operation| !matches!(operation, Operation::Compare))
            .count();
        assert_eq!(transfers, 12 * n + 19, "{n} entries");
    }
}
