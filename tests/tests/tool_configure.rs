//! The configuration tool (`safety-config`) against the host simulation: a two-node network
//! configured from a network file by the procedure of EN 50325-5 8.3.1, verified, started;
//! and the ways it must refuse or stop: a wrong identity (SC_REQ_37/38), a corrupted
//! read-back, a node that stops answering. The oracles are the simulated nodes themselves
//! (their 0x13FE, their NMT state, their outputs), not the tool's own reports.

use safety_config::ToolError;
use safety_config::client::Client;
use safety_config::network_file::{self, Network as NetworkFile};
use safety_config::procedure::{self, NodeResult, Quiet, Verdict};
use safety_config::transport::{Transport, TransportError};
use shared::canopen::nmt::NmtState;
use shared::safety::config::CONFIGURATION_VALID;
use shared::{CanFrame, Duration};
use std::time::Duration as StdDuration;
use system_tests::bus::{Fault, Injection, Match};
use system_tests::network::Network;
use system_tests::tool_bus::SimulatedBus;

const FILE: &str = r#"
[bus]
sdo_timeout_ms = 200

[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 25
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, serial = 33 }

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 50
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["0x6200:1:8", "output_inverted"]
"#;

fn network_file() -> NetworkFile {
    network_file::parse(FILE, "network.toml").expect("the test's network file is valid")
}

/// Two nodes, powered on and booted (pre-operational), and the tool on the bus.
fn simulated() -> Client<SimulatedBus> {
    let mut net = Network::new(500_000, &[(1, "node 1"), (33, "node 33")]);
    net.run_for(Duration::from_millis(50));
    Client::new(SimulatedBus::new(net), StdDuration::from_millis(200))
}

fn configuration_valid(client: &Client<SimulatedBus>, id: u8) -> u8 {
    let net = &client.transport.net;
    net.devices[net.index_of(id)]
        .node
        .safety_config()
        .configuration_valid
}

fn quiet() -> Quiet {
    Quiet {
        accept_identity: false,
    }
}

#[test]
fn en50325_5_8_3_1_configure_verify_start_two_nodes_from_a_file() {
    let file = network_file();
    let mut client = simulated();
    // The producer's application holds its input (released: 0) with the inverted copy, as
    // its two channels do.
    let producer = client.transport.net.index_of(1);
    client.transport.net.set_input(producer, 0);
    let report = procedure::configure(&mut client, &file, true, &mut quiet()).unwrap();
    assert!(report.success(), "{report:?}");
    assert!(report.started);
    for id in [1, 33] {
        assert_eq!(
            configuration_valid(&client, id),
            CONFIGURATION_VALID,
            "node {id}"
        );
    }
    // The node's own signature (shared's CRC) equals the tool's (its own CRC).
    let net = &client.transport.net;
    let node_33 = net.devices[net.index_of(33)].node.safety_config().srdos[0];
    assert_eq!(node_33.cob_id_1, 0x101);
    assert_eq!(
        node_33.signature,
        shared::safety::signature::compute(&node_33)
    );

    client.transport.net.run_for(Duration::from_millis(300));
    let net = &mut client.transport.net;
    for id in [1, 33] {
        assert_eq!(
            net.state(net.index_of(id)),
            NmtState::Operational,
            "node {id}"
        );
    }
    let consumer = net.index_of(33);
    assert_eq!(net.devices[consumer].node.fault(), None);
    let received = net.devices[consumer].pairs_received;
    assert!(received >= 5, "only {received} SRDO pairs in 300 ms");
    // The mapping carries the input to the output.
    net.set_input(producer, 1);
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.output(consumer), 1);

    // Verify in Operational: everything matches.
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    assert_eq!(
        verdicts,
        vec![Verdict::Matches { node: 1 }, Verdict::Matches { node: 33 }]
    );
}

#[test]
fn en50325_5_8_3_1_verify_reports_a_node_that_was_not_configured() {
    let file = network_file();
    let mut client = simulated();
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    // Node 1's pre-defined connection set equals the file except that it is unsigned; node
    // 33's pre-defined COB-IDs (141h/142h) differ from the file.
    match &verdicts[0] {
        Verdict::Differs { node: 1, diff } => {
            assert!(!diff.is_empty());
            assert!(
                diff.iter()
                    .all(|line| line.starts_with("signature of SRDO")),
                "{diff:?}"
            );
            // The tool's CRC gives the golden value of shared's tests for this record.
            assert!(diff[0].contains("191Ah"), "{diff:?}");
        }
        other => panic!("node 1: {other:?}"),
    }
    match &verdicts[1] {
        Verdict::Differs { node: 33, diff } => {
            assert!(
                diff.iter()
                    .any(|line| line.contains("COB-ID 1") && line.contains("file 101h, node 141h")),
                "{diff:?}"
            );
        }
        other => panic!("node 33: {other:?}"),
    }
}

#[test]
fn sc_req_37_wrong_identity_is_refused_before_any_write() {
    let text = FILE.replace("serial = 33", "serial = 34");
    let file = network_file::parse(&text, "network.toml").unwrap();
    let mut client = simulated();
    let before = client.transport.net.devices[1].node.safety_config().clone();
    let error = procedure::configure_node(&mut client, &file.nodes[1], &mut quiet()).unwrap_err();
    assert!(
        matches!(error, ToolError::IdentityMismatch { node: 33, .. }),
        "{error}"
    );
    let message = error.to_string();
    assert!(
        message.contains("serial number: file 22h, node 21h"),
        "{message}"
    );
    // Nothing was written.
    assert_eq!(
        *client.transport.net.devices[1].node.safety_config(),
        before
    );
    assert_eq!(client.transport.net.state(1), NmtState::PreOperational);

    // With the explicit override it goes ahead.
    let mut accept = Quiet {
        accept_identity: true,
    };
    procedure::configure_node(&mut client, &file.nodes[1], &mut accept).unwrap();
    assert_eq!(configuration_valid(&client, 33), CONFIGURATION_VALID);
}

/// Flips one bit of the first SDO upload answer for `object` from `node`: a node (or a path)
/// that returns one wrong value on read-back.
struct CorruptOneRead {
    inner: SimulatedBus,
    node: u8,
    object: (u16, u8),
    done: bool,
}

impl Transport for CorruptOneRead {
    fn now(&mut self) -> StdDuration {
        self.inner.now()
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.inner.send(frame)
    }
    fn receive(&mut self, deadline: StdDuration) -> Result<Option<CanFrame>, TransportError> {
        let Some(frame) = self.inner.receive(deadline)? else {
            return Ok(None);
        };
        let data = frame.data();
        let [lo, hi] = self.object.0.to_le_bytes();
        let upload_answer =
            data.len() == 8 && data[0] & 0xE0 == 0x40 && data[1..4] == [lo, hi, self.object.1];
        if !self.done && frame.id().raw() == 0x580 + u16::from(self.node) && upload_answer {
            self.done = true;
            let mut bytes = [0u8; 8];
            bytes.copy_from_slice(data);
            bytes[4] ^= 0x02;
            return Ok(Some(CanFrame::new(frame.id(), &bytes).unwrap()));
        }
        Ok(Some(frame))
    }
}

#[test]
fn en50325_5_8_3_1_corrupted_read_back_is_caught_and_left_invalid() {
    let file = network_file();
    let Client { transport, .. } = simulated();
    let transport = CorruptOneRead {
        inner: transport,
        node: 33,
        object: (0x1301, 5),
        done: false,
    };
    let mut client = Client::new(transport, StdDuration::from_millis(200));
    let report = procedure::configure(&mut client, &file, true, &mut quiet()).unwrap();
    assert!(!report.success());
    assert!(!report.started, "no node may be started after a failure");
    assert!(client.transport.done, "the fault was injected");
    match &report.nodes[1] {
        NodeResult::Failed { node: 33, error } => {
            assert!(
                error.contains("SRDO 1 COB-ID 1 (1301h:05h): file 101h, node 103h"),
                "{error}"
            );
            assert!(error.contains("left invalid"), "{error}");
        }
        other => panic!("{other:?}"),
    }
    let net = &client.transport.inner.net;
    let consumer = net.index_of(33);
    assert_ne!(
        net.devices[consumer]
            .node
            .safety_config()
            .configuration_valid,
        CONFIGURATION_VALID
    );
    assert_eq!(net.state(consumer), NmtState::PreOperational);
    // Node 1 was configured before and is valid, but was not started either.
    assert_eq!(
        net.devices[net.index_of(1)]
            .node
            .safety_config()
            .configuration_valid,
        CONFIGURATION_VALID
    );
    assert_eq!(net.state(net.index_of(1)), NmtState::PreOperational);
}

/// Mutes `node` on the bus after it has been sent `after` SDO requests: a node that stops
/// answering in the middle of its configuration (power lost, cable pulled).
struct Silenced {
    inner: SimulatedBus,
    node: u8,
    after: u32,
    requests: u32,
}

impl Transport for Silenced {
    fn now(&mut self) -> StdDuration {
        self.inner.now()
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        if frame.id().raw() == 0x600 + u16::from(self.node) {
            self.requests += 1;
            if self.requests == self.after {
                let net = &mut self.inner.net;
                let participant = net.index_of(self.node) + 1;
                net.bus.inject(Injection::new(
                    Match::all_from(participant, net.now),
                    Fault::Mute,
                ));
            }
        }
        self.inner.send(frame)
    }
    fn receive(&mut self, deadline: StdDuration) -> Result<Option<CanFrame>, TransportError> {
        self.inner.receive(deadline)
    }
}

#[test]
fn en50325_5_8_3_1_node_that_stops_answering_is_named_and_left_invalid() {
    let file = network_file();
    let Client { transport, .. } = simulated();
    // Identity (4) + 0x13FF:0 + direction 0 + mapping count: the 8th request, mid-mapping.
    let transport = Silenced {
        inner: transport,
        node: 33,
        after: 8,
        requests: 0,
    };
    let mut client = Client::new(transport, StdDuration::from_millis(200));
    let report = procedure::configure(&mut client, &file, false, &mut quiet()).unwrap();
    match &report.nodes[1] {
        NodeResult::Failed { node: 33, error } => {
            assert!(
                error.starts_with("node 33 did not answer within 200 ms"),
                "{error}"
            );
        }
        other => panic!("{other:?}"),
    }
    let net = &client.transport.inner.net;
    assert_eq!(
        net.devices[net.index_of(33)]
            .node
            .safety_config()
            .configuration_valid,
        0
    );
    // And verify says so too.
    let verdicts = procedure::verify(&mut client, &file).unwrap();
    assert!(
        matches!(&verdicts[1], Verdict::Unreachable { node: 33, error } if error.contains("node 33 did not answer")),
        "{verdicts:?}"
    );
    assert_eq!(verdicts[0], Verdict::Matches { node: 1 });
}

/// A node whose flash erase holds the processor (the hardware's medium) writes each store to
/// a slot erased at start-up. A store that finds its slot not erased refuses with
/// 0800 0022h (CiA 301 7.5.2.13, EN 50325-5 8.3.1's store step), nothing written, and the
/// tool says in words why and what to do instead of quoting the abort code.
#[test]
fn en50325_5_8_3_1_a_store_refused_until_a_power_cycle_is_explained() {
    use shared::canopen::storage::RamFlash;
    let mut client = simulated();
    let net = &mut client.transport.net;
    let index = net.index_of(33);
    *net.devices[index].node.flash_mut() = RamFlash::new().with_stalling_erase();

    // A new node's medium is blank: its first two stores find their slot erased. The
    // third would write the first store's slot again, which only a start-up erases.
    for store in ["first", "second"] {
        client
            .write(33, procedure::STORE_PARAMETERS, b"save")
            .unwrap_or_else(|error| panic!("the {store} store is taken: {error}"));
    }
    let error = procedure::store(&mut client, 33).expect_err("the third store is refused");
    assert!(
        matches!(error, ToolError::StoreRefused { node: 33 }),
        "{error:?}"
    );
    let sentence = error.to_string();
    for words in ["node 33", "08000022h", "not stored", "power-cycle"] {
        assert!(sentence.contains(words), "{sentence}");
    }
}
