//! The configuration tool configuring SimpleCAN nodes on the host simulation
//! (docs/simplecan.md section 11; SC_REQ_35, SC_REQ_36): written, read back, signed with the
//! tool's CRC-32, declared valid and stored, then verified. The oracles are the simulated
//! nodes' objects, read by the simulation's own SDO client, not the tool's reports.
//! The nodes are `shared::node::SimpleCanNode`s (the SRDO table and SimpleCAN in one slot)
//! on the simulated bus of `system_tests::simplecan_net`.

use safety_config::client::Client;
use safety_config::network_file;
use safety_config::procedure::{self, Quiet, Verdict};
use shared::Duration;
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::canopen::od::Address;
use std::time::Duration as StdDuration;
use system_tests::simplecan_net::ScNetwork;
use system_tests::tool_bus::SimulatedBus;

const FILE: &str = r#"
[bus]
sdo_timeout_ms = 200

[simplecan]
network_name = "host simulation"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 500

[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }
[node.simplecan]
potential_master = true
produce = [
  { sc_id = 0x30, slot = 0, object = "input" },
  { sc_id = 0x31, slot = 1, object = "input_inverted" },
]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[node.simplecan]
consume = [
  { sc_id = 0x30, timeout_ms = 50, object = "output" },
  { sc_id = 0x31, timeout_ms = 50, object = "output_inverted" },
]
"#;

/// The object as the simulation's own SDO client reads it (not the tool's code).
fn read(client: &mut Client<SimulatedBus<ScNetwork>>, id: u8, index: u16, sub: u8) -> u32 {
    let bytes = client
        .transport
        .net
        .read(id, Address::new(index, sub))
        .unwrap_or_else(|error| panic!("node {id} {index:04X}h:{sub:02X}h: {error:?}"));
    let mut raw = [0u8; 4];
    raw[..bytes.len()].copy_from_slice(&bytes);
    u32::from_le_bytes(raw)
}

#[test]
fn sc_req_35_and_sc_req_36_configure_and_verify_simplecan_nodes_on_the_host_simulation() {
    let file = network_file::parse(FILE, "network.toml").unwrap();
    let mut net = ScNetwork::new(500_000, &[1, 33]);
    net.run_for(Duration::from_millis(50));
    let mut client = Client::new(SimulatedBus::new(net), StdDuration::from_millis(200));
    let mut quiet = Quiet {
        accept_identity: false,
    };
    let report = procedure::configure(&mut client, &file, false, &mut quiet).unwrap();
    assert!(report.success(), "{report:?}");
    let expected = procedure::offline_simplecan(&file);
    for (config, signature) in &expected {
        let id = config.node_id;
        assert_eq!(read(&mut client, id, 0x5EFE, 0), 0xA5, "node {id}: 5EFEh");
        assert_eq!(
            read(&mut client, id, 0x5EFF, 0),
            *signature,
            "node {id}: 5EFFh"
        );
        assert_eq!(
            read(&mut client, id, 0x5E01, 0) as usize,
            config.entries.len(),
            "node {id}: 5E01h"
        );
        for (n, entry) in (0u16..).zip(&config.entries) {
            assert_eq!(
                read(&mut client, id, 0x5E10 + n, 5),
                entry.hash,
                "node {id}"
            );
        }
    }
    assert_eq!(
        procedure::verify(&mut client, &file).unwrap(),
        vec![Verdict::Matches { node: 1 }, Verdict::Matches { node: 33 }]
    );
    // SC_REQ_34: each node recomputes the signature the tool wrote (by the `crc` crate, not
    // the tool's code) at NMT start, and accepts it: both reach Operational, no cause.
    let net = &mut client.transport.net;
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(100));
    for id in [1, 33] {
        assert_eq!(net.state(id), NmtState::Operational, "node {id}");
        assert_eq!(net.protocol_cause(id), None, "node {id}");
    }
}
