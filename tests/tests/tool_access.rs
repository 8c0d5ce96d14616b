//! Protection against unauthorised configuration (SC_REQ_43) through the configuration tool
//! (`safety-config`'s library) against the host simulation: every refused path (locked, wrong
//! secret, expired unlock, too many attempts), a change made with the unlock and its audit
//! record, and both channels of a dual-channel node agreeing after it. The oracles are the
//! simulated nodes themselves (their configuration, their access state, their NMT state).

use safety_config::ToolError;
use safety_config::access::{self, Secret};
use safety_config::client::Client;
use safety_config::network_file::{self, Network as NetworkFile};
use safety_config::procedure::{self, NodeResult, Operator};
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::node::access::{AccessState, UNLOCK_PERIOD, lockout};
use shared::safety::config::CONFIGURATION_VALID;
use shared::{Duration, Instant};
use std::time::Duration as StdDuration;
use system_tests::dual::{DualNetwork, Side};
use system_tests::network::Network;
use system_tests::tool_bus::{SimulatedBus, client};

const SECRET: &[u8] = b"site secret 0042";
const SALT: [u8; 16] = *b"a fixed salt 16B";

/// Node 33 consuming node 1's SRDO, at the SCT given.
fn network_file(sct_ms: u16) -> NetworkFile {
    let text = format!(
        r#"
[bus]
sdo_timeout_ms = 200

[[node]]
id = 33
name = "safe output"
identity = {{ vendor = 0xABC, product = 0x304, serial = 33 }}

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = {sct_ms}
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#
    );
    network_file::parse(&text, "network.toml").expect("the test's network file is valid")
}

/// An operator that gives this secret (or none) and records what it was told.
struct Maintainer {
    secret: Option<&'static [u8]>,
    notes: Vec<String>,
}

impl Maintainer {
    fn with(secret: Option<&'static [u8]>) -> Self {
        Maintainer {
            secret,
            notes: Vec::new(),
        }
    }
}

impl Operator for Maintainer {
    fn note(&mut self, line: &str) {
        self.notes.push(line.to_owned());
    }
    fn confirm_identity(&mut self, _: &network_file::NodeSpec, _: &str) -> bool {
        false
    }
    fn secret(&mut self, _node: u8) -> Result<Option<Secret>, ToolError> {
        self.secret
            .map(|bytes| Secret::new(bytes.to_vec()))
            .transpose()
    }
}

fn secret(bytes: &[u8]) -> Secret {
    Secret::new(bytes.to_vec()).unwrap()
}

/// Node 33 configured (SCT 50 ms) while new, given its secret, stored, and reset: a
/// commissioned device, locked.
fn commissioned() -> Client<SimulatedBus<Network>> {
    let mut net = Network::new(500_000, &[(33, "node 33")]);
    net.run_for(Duration::from_millis(50));
    let mut client = Client::new(SimulatedBus::new(net), StdDuration::from_millis(200));
    let report = procedure::configure(
        &mut client,
        &network_file(50),
        false,
        &mut Maintainer::with(None),
    )
    .unwrap();
    assert!(
        report.success(),
        "a new device is configured without a secret"
    );
    access::set_secret_with_salt(&mut client, 33, &secret(SECRET), SALT).unwrap();
    client.nmt(NmtCommand::ResetNode, 33).unwrap();
    client.transport.net.run_for(Duration::from_millis(20));
    assert_eq!(access::state(&mut client, 33).unwrap(), AccessState::Locked);
    client
}

fn node_33(
    client: &Client<SimulatedBus<Network>>,
) -> &shared::node::Node<impl shared::canopen::storage::Flash, 4> {
    let net = &client.transport.net;
    &net.devices[net.index_of(33)].node
}

fn sct(client: &Client<SimulatedBus<Network>>) -> u16 {
    node_33(client).safety_config().srdos[0].cycle_time
}

fn failed(report: &procedure::ConfigureReport) -> &str {
    match &report.nodes[0] {
        NodeResult::Failed { error, .. } => error,
        NodeResult::Done(done) => panic!("configured: {done:?}"),
    }
}

#[test]
fn sc_req_43_a_locked_node_refuses_the_configuration_and_nothing_is_written() {
    let mut client = commissioned();
    let report = procedure::configure(
        &mut client,
        &network_file(120),
        false,
        &mut Maintainer::with(None),
    )
    .unwrap();
    let error = failed(&report);
    assert!(error.contains("node 33 is locked"), "{error}");
    assert_eq!(sct(&client), 50, "nothing was written");
    assert_eq!(
        node_33(&client).safety_config().configuration_valid,
        CONFIGURATION_VALID,
        "the validated configuration stays valid"
    );
    // A single write and a store are refused alike.
    for (address, data) in [
        (Address::new(0x1301, 2), &120u16.to_le_bytes()[..]),
        (Address::new(0x1010, 1), &b"save"[..]),
        (Address::new(0x1011, 1), &b"load"[..]),
    ] {
        let error = client.write(33, address, data).unwrap_err();
        assert!(
            error.to_string().contains("06010000h"),
            "{address:?}: {error}"
        );
        // The tool's `write` says what to do instead of quoting the code.
        assert!(matches!(
            access::explain_refusal(error),
            ToolError::Locked { node: 33 }
        ));
    }
    // So is a new secret.
    assert!(matches!(
        access::set_secret_with_salt(&mut client, 33, &secret(b"takeover secret"), [0; 16]),
        Err(ToolError::Locked { node: 33 })
    ));
}

#[test]
fn sc_req_43_a_wrong_secret_is_refused_and_nothing_is_written() {
    let mut client = commissioned();
    let mut maintainer = Maintainer::with(Some(b"wrong secret"));
    let report =
        procedure::configure(&mut client, &network_file(120), false, &mut maintainer).unwrap();
    let error = failed(&report);
    assert!(error.contains("refused the secret"), "{error}");
    assert_eq!(sct(&client), 50);
    assert_eq!(node_33(&client).access().failures(), 1);
}

#[test]
fn sc_req_43_too_many_attempts_lock_out_even_the_right_secret() {
    let mut client = commissioned();
    for attempt in 1..=3u16 {
        let error = access::unlock(&mut client, 33, &secret(b"guess")).unwrap_err();
        let ToolError::WrongSecret { lockout_ms, .. } = error else {
            panic!("attempt {attempt}: {error}");
        };
        assert_eq!(
            u64::from(lockout_ms) * 1000,
            lockout(attempt).as_micros(),
            "attempt {attempt}"
        );
        client
            .transport
            .net
            .run_for(Duration::from_micros(lockout(attempt).as_micros()));
    }
    let error = access::unlock(&mut client, 33, &secret(b"guess")).unwrap_err();
    assert!(matches!(error, ToolError::WrongSecret { .. }), "{error}");
    // NMT reset node, which anyone on the bus may send, does not clear the lockout.
    client.nmt(NmtCommand::ResetNode, 33).unwrap();
    client.transport.net.run_for(Duration::from_millis(20));
    let report = procedure::configure(
        &mut client,
        &network_file(120),
        false,
        &mut Maintainer::with(Some(SECRET)),
    )
    .unwrap();
    let error = failed(&report);
    assert!(
        error.contains("locked out after too many failed attempts"),
        "{error}"
    );
    assert_eq!(sct(&client), 50);
    assert_eq!(node_33(&client).access().failures(), 4);
}

#[test]
fn sc_req_43_an_expired_unlock_refuses_the_change() {
    let mut client = commissioned();
    access::unlock(&mut client, 33, &secret(SECRET)).unwrap();
    client
        .transport
        .net
        .run_for(Duration::from_micros(UNLOCK_PERIOD.as_micros()));
    assert_eq!(access::state(&mut client, 33).unwrap(), AccessState::Locked);
    let report = procedure::configure(
        &mut client,
        &network_file(120),
        false,
        &mut Maintainer::with(None),
    )
    .unwrap();
    assert!(failed(&report).contains("node 33 is locked"));
    assert_eq!(sct(&client), 50);
}

#[test]
fn sc_req_43_an_unlocked_change_is_made_and_recorded_in_the_audit_record() {
    let mut client = commissioned();
    let before = access::read_audit(&mut client, 33).unwrap();
    assert_eq!(
        before.changes, 1,
        "the commissioning was a validated change"
    );
    let mut maintainer = Maintainer::with(Some(SECRET));
    let report =
        procedure::configure(&mut client, &network_file(120), false, &mut maintainer).unwrap();
    assert!(report.success(), "{report:?}");
    assert!(maintainer.notes.iter().any(|n| n.contains("unlocked")));
    assert_eq!(sct(&client), 120);
    let NodeResult::Done(done) = &report.nodes[0] else {
        unreachable!()
    };
    let new_signature = done.signatures[0].1;
    // Reset: the audit record was stored with the parameters.
    client.nmt(NmtCommand::ResetNode, 33).unwrap();
    client.transport.net.run_for(Duration::from_millis(20));
    let audit = access::read_audit(&mut client, 33).unwrap();
    assert_eq!(audit.changes, 2);
    assert_eq!(audit.before, before.after);
    assert_eq!(audit.after[0], new_signature);
    let held: Vec<u16> = node_33(&client)
        .safety_config()
        .srdos
        .iter()
        .map(|record| record.signature)
        .collect();
    assert_eq!(audit.after, held, "the signatures the node holds (0x13FF)");
    assert_eq!(sct(&client), 120, "the change was stored");
    assert_eq!(access::state(&mut client, 33).unwrap(), AccessState::Locked);
}

#[test]
fn sc_req_43_an_open_node_is_reported_open_to_a_tool_with_a_secret() {
    let mut net = Network::new(500_000, &[(33, "node 33")]);
    net.run_for(Duration::from_millis(50));
    let mut client = Client::new(SimulatedBus::new(net), StdDuration::from_millis(200));
    let mut maintainer = Maintainer::with(Some(SECRET));
    let report =
        procedure::configure(&mut client, &network_file(50), false, &mut maintainer).unwrap();
    assert!(report.success());
    assert!(
        maintainer.notes.iter().any(|n| n.contains("has no secret")),
        "{:?}",
        maintainer.notes
    );
}

/// Both channels of a dual-channel node follow the same unlock and the same change: after an
/// unlocked change, stored and started, the configuration digests on the link agree, both
/// channels are Operational and working, and both hold the same audit record.
#[test]
fn sc_req_43_both_channels_agree_after_an_unlocked_change() {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start()
        .expect("new devices are configured");
    net.run_for(Duration::from_millis(200));
    net.nmt(NmtCommand::EnterPreOperational, 0);
    net.run_for(Duration::from_millis(20));
    access::set_secret_with_salt(&mut client(&mut net), 33, &secret(SECRET), SALT).unwrap();
    net.nmt(NmtCommand::ResetNode, 0);
    net.run_for(Duration::from_millis(200));
    for side in [Side::A, Side::B] {
        let channel = match side {
            Side::A => net.node(33).a.node().access().state(Instant::ZERO),
            Side::B => net.node(33).b.node().access().state(Instant::ZERO),
        };
        assert_eq!(channel, AccessState::Locked, "{side:?}");
    }
    {
        let mut tool = client(&mut net);
        access::unlock(&mut tool, 33, &secret(SECRET)).unwrap();
        tool.write(33, Address::new(0x1301, 2), &80u16.to_le_bytes())
            .unwrap();
        procedure::sign_and_validate(&mut tool, 33, &[1]).unwrap();
        procedure::store(&mut tool, 33).unwrap();
    }
    net.set_inputs(1, 1, 1);
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(300));
    let node = net.node(33);
    for (side, channel) in [("A", node.a.node()), ("B", node.b.node())] {
        assert_eq!(channel.nmt_state(), NmtState::Operational, "{side}");
        assert_eq!(channel.safety_config().srdos[0].cycle_time, 80, "{side}");
        assert_eq!(channel.access().audit().changes, 2, "{side}");
    }
    assert!(
        node.a.is_working() && node.b.is_working(),
        "{:?} {:?}",
        node.a.fault(),
        node.b.fault()
    );
    assert_eq!(
        node.a.node().access().audit(),
        node.b.node().access().audit()
    );
    assert_eq!(net.output(33), 1, "the output follows node 1's input");
}
