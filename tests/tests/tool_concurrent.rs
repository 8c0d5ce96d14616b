//! The configuration tool on several nodes side by side (`procedure::configure_concurrently`,
//! `verify_concurrently`): one socketcand connection per node to the host simulation behind
//! `socketcand_sim` (nodes 1 and 33 of `system_tests::network`, run in real time), each node
//! configured by the steps of EN 50325-5 8.3.1 and verified, with both nodes' SDO transfers
//! in flight at once (CiA 301 7.2.4: one transfer at a time per SDO server, and each node is
//! its own server).

use safety_config::client::Client;
use safety_config::procedure::{self, NodeResult, Quiet, Verdict};
use safety_config::socketcand::SocketcandClient;
use safety_config::transport::{Transport, TransportError};
use safety_config::{ToolError, network_file};
use shared::CanFrame;
use std::process::{Child, Command};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

/// Nodes 1 and 33 with SRDOs other than the ones `socketcand_sim` set up, so that the tool's
/// writes change what the nodes hold.
const FILE: &str = r#"
[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }

[[node.srdo]]
number = 2
direction = "transmit"
refresh_time_ms = 50
srvt_ms = 20
cob_ids = [0x103, 0x104]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 400
srvt_ms = 80
cob_ids = [0x103, 0x104]
mapping = ["output", "output_inverted"]
"#;

/// What configuring one node gave: node-ID, each SRDO's signature, SDO requests.
type Done = (u8, Vec<(u8, u16)>, u64);

/// `socketcand_sim`, killed when dropped.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `socketcand_sim` on a free port and returns it with its address.
fn server() -> (Server, String) {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new(env!("CARGO_BIN_EXE_socketcand_sim"))
        .arg(port.to_string())
        .spawn()
        .expect("socketcand_sim starts");
    (Server(child), format!("127.0.0.1:{port}"))
}

/// A connection to the server, retried while the simulation configures its nodes.
fn connect(address: &str) -> SocketcandClient {
    let give_up = std::time::Instant::now() + Duration::from_secs(60);
    loop {
        match SocketcandClient::connect(address, "can0") {
            Ok(client) => return client,
            Err(error) if std::time::Instant::now() >= give_up => {
                panic!("socketcand_sim did not accept a connection: {error}")
            }
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

/// Where the clients meet: how many have sent their first request, and whether one gave up
/// waiting for the others.
#[derive(Default)]
struct Meeting {
    arrived: Mutex<(usize, bool)>,
    all_here: Condvar,
}

/// A transport whose first send waits until every client of the meeting has come to its own
/// first send: were the nodes configured one after another, the first would wait alone and
/// give up (after 20 s, which only a sequential run ever reaches), and the test says so.
struct Gate<T> {
    inner: T,
    meeting: Arc<Meeting>,
    expected: usize,
    passed: bool,
}

impl<T: Transport> Transport for Gate<T> {
    fn now(&mut self) -> Duration {
        self.inner.now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        if !self.passed {
            self.passed = true;
            let mut arrived = self.meeting.arrived.lock().unwrap();
            arrived.0 += 1;
            self.meeting.all_here.notify_all();
            let (mut arrived, _) = self
                .meeting
                .all_here
                .wait_timeout_while(arrived, Duration::from_secs(20), |(count, _)| {
                    *count < self.expected
                })
                .unwrap();
            if arrived.0 < self.expected {
                arrived.1 = true;
            }
        }
        self.inner.send(frame)
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        self.inner.receive(deadline)
    }
}

/// Both nodes are configured, each over its own connection, with both connections' first
/// requests out before either goes on (the nodes side by side, not in turn); each node gets
/// the file's SRDOs, signed, valid and stored, and `verify_concurrently` finds both matching
/// the file. Each node takes the requests and gets the signatures that configuring the nodes
/// in turn over one connection gives.
#[test]
fn two_nodes_are_configured_and_verified_side_by_side_each_over_its_own_connection() {
    let network = network_file::parse(FILE, "two nodes").unwrap();
    let (_server, address) = server();
    let meeting = Arc::new(Meeting::default());
    let mut clients: Vec<Client<Gate<SocketcandClient>>> = network
        .nodes
        .iter()
        .map(|_| {
            Client::new(
                Gate {
                    inner: connect(&address),
                    meeting: meeting.clone(),
                    expected: network.nodes.len(),
                    passed: false,
                },
                Duration::from_secs(2),
            )
        })
        .collect();
    let report = procedure::configure_concurrently(
        &mut clients,
        &network,
        false,
        &mut Quiet {
            accept_identity: false,
        },
    )
    .unwrap();
    let (arrived, gave_up) = *meeting.arrived.lock().unwrap();
    assert_eq!(arrived, 2);
    assert!(
        !gave_up,
        "a client waited alone: the nodes were not side by side"
    );
    assert!(report.success(), "{:?}", report.nodes);
    assert!(!report.started);
    let done = |report: &procedure::ConfigureReport| -> Vec<Done> {
        report
            .nodes
            .iter()
            .map(|result| match result {
                NodeResult::Done(done) => (done.node, done.signatures.clone(), done.sdo_requests),
                NodeResult::Failed { node, error } => panic!("node {node}: {error}"),
            })
            .collect()
    };
    let side_by_side = done(&report);
    let numbers: Vec<(u8, Vec<u8>)> = side_by_side
        .iter()
        .map(|(node, signed, _)| (*node, signed.iter().map(|(n, _)| *n).collect()))
        .collect();
    assert_eq!(numbers, [(1, vec![1, 2, 3, 4]), (33, vec![1, 2, 3, 4])]);
    let verdicts = procedure::verify_concurrently(&mut clients, &network).unwrap();
    assert_eq!(
        verdicts,
        [Verdict::Matches { node: 1 }, Verdict::Matches { node: 33 }]
    );
    // The nodes in turn over one connection: the same requests per node and the same
    // signatures, and the same verdicts.
    let quiet = &mut Quiet {
        accept_identity: false,
    };
    let in_turn = procedure::configure(&mut clients[0], &network, false, quiet).unwrap();
    assert_eq!(done(&in_turn), side_by_side);
    let verdicts = procedure::verify(&mut clients[0], &network).unwrap();
    assert_eq!(
        verdicts,
        [Verdict::Matches { node: 1 }, Verdict::Matches { node: 33 }]
    );
}

/// Fewer connections than nodes is refused before anything is sent, with a sentence that
/// counts both.
#[test]
fn side_by_side_with_fewer_clients_than_nodes_is_refused_before_any_request() {
    let network = network_file::parse(FILE, "two nodes").unwrap();
    let (_server, address) = server();
    let mut clients = vec![Client::new(connect(&address), Duration::from_secs(2))];
    let error = procedure::verify_concurrently(&mut clients, &network).unwrap_err();
    assert!(
        matches!(&error, ToolError::Usage(sentence) if sentence.contains("2 node(s)") && sentence.contains("1 client(s)")),
        "{error}"
    );
    assert_eq!(clients[0].requests, 0);
}
