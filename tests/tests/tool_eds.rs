//! The EDS and DCFs of the configuration tool against the simulated nodes: the EDS lists
//! exactly what a node serves, with its data types, defaults and read-only entries; a DCF
//! exported from a configured node configures and verifies a node again, and one whose
//! values do not match its signatures is refused with its position.

use safety_config::client::Client;
use safety_config::eds;
use safety_config::network_file::{self, Network as NetworkFile};
use safety_config::procedure::{self, Quiet, Verdict};
use shared::Duration;
use shared::canopen::od::{AbortCode, Address};
use std::time::Duration as StdDuration;
use system_tests::network::Network;
use system_tests::tool_bus::SimulatedBus;

const FILE: &str = r#"
[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 40
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, serial = 33 }

[[node.srdo]]
number = 2
direction = "receive"
sct_ms = 120
srvt_ms = 30
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#;

/// Nodes 1 and 33 as channel A's image describes them (its device name included).
fn simulated() -> Client<SimulatedBus> {
    let name = dual_channel::device::CHANNEL_A_NAME;
    let mut net = Network::new(500_000, &[(1, name), (33, name)]);
    net.run_for(Duration::from_millis(50));
    Client::new(SimulatedBus::new(net), StdDuration::from_millis(200))
}

fn quiet() -> Quiet {
    Quiet {
        accept_identity: false,
    }
}

/// The bytes of a data type (VISIBLE_STRING: any).
fn length(data_type: u16) -> Option<usize> {
    match data_type {
        0x0005 => Some(1),
        0x0006 => Some(2),
        0x0007 => Some(4),
        _ => None,
    }
}

/// Every entry of the EDS is served by the node with its data type's length and, where the
/// EDS gives one, its default value; every read-only entry refuses a write (0601 0002h); no
/// other object answers in the communication, manufacturer and profile ranges probed.
#[test]
fn cia306_the_eds_lists_exactly_what_the_node_serves() {
    let mut client = simulated();
    let objects = eds::objects();
    for node in [1u8, 33] {
        for object in &objects {
            for entry in &object.entries {
                if entry.access == "wo" {
                    let error = client
                        .read(node, entry.address)
                        .expect_err("a write-only entry refuses reads");
                    assert_eq!(
                        error.sdo_client_error(),
                        Some(shared::canopen::sdo_client::ClientError::Aborted(
                            AbortCode::WriteOnly
                        )),
                        "{:04X}h:{:02X}h: {error}",
                        entry.address.index,
                        entry.address.sub
                    );
                    continue;
                }
                let bytes = client
                    .read(node, entry.address)
                    .unwrap_or_else(|error| panic!("node {node}: {error}"));
                if let Some(len) = length(entry.data_type) {
                    assert_eq!(bytes.len(), len, "node {node} {:?}", entry.address);
                }
                let Some(default) = &entry.default else {
                    continue;
                };
                let expected = if default == "$NODEID+0" {
                    u64::from(node)
                } else if let Some(hex) = default.strip_prefix("0x") {
                    u64::from_str_radix(hex, 16).unwrap()
                } else if let Ok(number) = default.parse::<u64>() {
                    number
                } else {
                    assert_eq!(String::from_utf8_lossy(&bytes), *default);
                    continue;
                };
                let mut raw = [0u8; 8];
                raw[..bytes.len()].copy_from_slice(&bytes);
                assert_eq!(
                    u64::from_le_bytes(raw),
                    expected,
                    "node {node} {:04X}h:{:02X}h ({})",
                    entry.address.index,
                    entry.address.sub,
                    entry.name
                );
            }
        }
    }
    for object in &objects {
        for entry in object.entries.iter().filter(|entry| entry.access == "ro") {
            let bytes = client.read(33, entry.address).unwrap();
            let error = client
                .write(33, entry.address, &bytes)
                .expect_err("a read-only entry refuses writes");
            assert_eq!(
                error.sdo_client_error(),
                Some(shared::canopen::sdo_client::ClientError::Aborted(
                    AbortCode::ReadOnly
                )),
                "{:04X}h:{:02X}h: {error}",
                entry.address.index,
                entry.address.sub
            );
        }
    }
    let listed: Vec<u16> = objects.iter().map(|object| object.index).collect();
    for index in (0x1000..=0x1FFF)
        .chain(0x5C00..=0x5C1F)
        .chain(0x6000..=0x62FF)
    {
        if listed.contains(&index) {
            continue;
        }
        let error = client
            .read(33, Address::new(index, 0))
            .expect_err("an object the EDS does not list");
        assert_eq!(
            error.sdo_client_error(),
            Some(shared::canopen::sdo_client::ClientError::Aborted(
                AbortCode::NoObject
            )),
            "{index:04X}h: {error}"
        );
    }
}

/// DCF export and import: the DCF of each configured node is the file's node again (identity,
/// SRDOs, signatures checked), configures a fresh network that then matches the original file,
/// and a DCF with one value changed is refused at that value's line.
#[test]
fn en50325_5_8_3_1_a_dcf_of_a_configured_node_configures_and_verifies_it_again() {
    let file: NetworkFile = network_file::parse(FILE, "network.toml").unwrap();
    let mut client = simulated();
    let report = procedure::configure(&mut client, &file, false, &mut quiet()).unwrap();
    assert!(report.success(), "{report:?}");
    let mut dcfs = Vec::new();
    for spec in &file.nodes {
        let dcf = procedure::read_dcf(&mut client, spec.id, spec.name.as_deref()).unwrap();
        let imported = network_file::parse_dcf(&dcf, "node.dcf").unwrap();
        assert_eq!(imported.nodes.len(), 1);
        let node = &imported.nodes[0];
        assert_eq!(node.id, spec.id);
        assert_eq!(node.name, spec.name);
        assert_eq!(node.srdos, spec.srdos, "node {}", spec.id);
        assert_eq!(node.identity.serial, spec.identity.serial);
        assert!(dcf.contains("ParameterValue=0xA5"), "0x13FE is recorded");
        dcfs.push((dcf, imported));
    }

    let mut fresh = simulated();
    for (_, imported) in &dcfs {
        let report = procedure::configure(&mut fresh, imported, false, &mut quiet()).unwrap();
        assert!(report.success(), "{report:?}");
    }
    let verdicts = procedure::verify(&mut fresh, &file).unwrap();
    assert_eq!(
        verdicts,
        vec![Verdict::Matches { node: 1 }, Verdict::Matches { node: 33 }]
    );

    // SRVT of node 33's SRDO 2 changed by hand: the signature no longer fits.
    let (dcf, _) = &dcfs[1];
    let section = dcf.find("[1302sub3]").unwrap();
    let key = section + dcf[section..].find("ParameterValue=").unwrap();
    let line = dcf[..key].matches('\n').count() + 1;
    let end = key + dcf[key..].find('\n').unwrap();
    let tampered = format!("{}ParameterValue=0x1F{}", &dcf[..key], &dcf[end..]);
    let error = network_file::parse_dcf(&tampered, "node-33.dcf").unwrap_err();
    assert!(error.message.contains("signature"), "{error}");
    let signature_line = tampered[..tampered.find("[13FFsub2]").unwrap()]
        .matches('\n')
        .count()
        + 1;
    assert!(
        error.line > signature_line && error.line < signature_line + 10,
        "{error} (SRVT at line {line})"
    );

    // A value out of its type's range is refused at its own line, not truncated.
    let section = dcf.find("[1382sub1]").unwrap();
    let key = section + dcf[section..].find("ParameterValue=").unwrap();
    let line = dcf[..key].matches('\n').count() + 1;
    let end = key + dcf[key..].find('\n').unwrap();
    let negative = format!("{}ParameterValue=-1{}", &dcf[..key], &dcf[end..]);
    let error = network_file::parse_dcf(&negative, "node-33.dcf").unwrap_err();
    assert_eq!(error.line, line, "{error}");
    assert!(error.message.contains("mapping entry 1 is -1"), "{error}");

    // A DCF without its node-ID is not a configured node's.
    let anonymous = dcf.replace("NodeID=33", "");
    let error = network_file::parse_dcf(&anonymous, "node-33.dcf").unwrap_err();
    assert!(error.message.contains("NodeID"), "{error}");
}

/// The sections of an EDS text: `[name]` → its `key=value` lines.
fn sections(text: &str) -> std::collections::BTreeMap<String, Vec<(String, String)>> {
    let mut sections = std::collections::BTreeMap::new();
    let mut current: Option<String> = None;
    for line in text.lines().map(str::trim) {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            current = Some(name.to_owned());
            sections.insert(name.to_owned(), Vec::new());
        } else if let (Some(name), Some((key, value))) = (&current, line.split_once('=')) {
            sections
                .get_mut(name)
                .expect("inserted")
                .push((key.to_owned(), value.to_owned()));
        }
    }
    sections
}

/// The SimpleCAN EDS (`docs/simplecan.md` section 11), parsed from its text: every
/// 5E00h..5EFFh entry it lists is served by an unconfigured SimpleCAN node with its data
/// type's length and its default value; a read-only one refuses a write (0601 0002h), a
/// writable one never with 0601 0002h; and the node serves no other object in 5E00h..5EFFh
/// (the entry after its last SDD entry is 0602 0000h).
#[test]
fn sc_req_16_the_simplecan_eds_lists_5e00h_to_5effh_as_the_node_serves_them() {
    use shared::canopen::sdo_client::ClientError;
    use system_tests::simplecan_net::ScNetwork;
    // ScDevice holds 4 SDD entries.
    const ENTRIES: u8 = 4;
    let mut net = ScNetwork::new(500_000, &[3]);
    net.run_for(Duration::from_millis(10));
    let mut client = Client::new(SimulatedBus::new(net), StdDuration::from_millis(200));
    let text = eds::simplecan_eds(ENTRIES);
    // Left for third-party readers (python-canopen's `import_od`).
    let kept = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("safety-node-simplecan.eds");
    std::fs::write(&kept, &text).unwrap_or_else(|error| panic!("{}: {error}", kept.display()));
    let sections = sections(&text);
    let mut checked = Vec::new();
    for (name, keys) in &sections {
        let Some((index, sub)) = name
            .split_once("sub")
            .or(Some((name.as_str(), "0")))
            .filter(|(index, _)| index.len() == 4 && index.starts_with("5E"))
        else {
            continue;
        };
        let get = |key: &str| {
            keys.iter()
                .find(|(k, _)| k == key)
                .map(|(_, value)| value.as_str())
        };
        if get("ObjectType") != Some("0x7") {
            continue;
        }
        let address = Address::new(
            u16::from_str_radix(index, 16).unwrap(),
            u8::from_str_radix(sub, 16).unwrap(),
        );
        let data_type =
            u16::from_str_radix(get("DataType").unwrap().trim_start_matches("0x"), 16).unwrap();
        let bytes = client
            .read(3, address)
            .unwrap_or_else(|error| panic!("[{name}]: {error}"));
        assert_eq!(Some(bytes.len()), length(data_type), "[{name}]");
        let default = get("DefaultValue").unwrap_or_else(|| panic!("[{name}] has a default"));
        let expected = match default.strip_prefix("0x") {
            Some(hex) => u64::from_str_radix(hex, 16).unwrap(),
            None => default.parse::<u64>().unwrap(),
        };
        let mut raw = [0u8; 8];
        raw[..bytes.len()].copy_from_slice(&bytes);
        assert_eq!(u64::from_le_bytes(raw), expected, "[{name}]");
        let written = client.write(3, address, &bytes).err();
        let read_only = written.as_ref().and_then(|error| error.sdo_client_error())
            == Some(ClientError::Aborted(AbortCode::ReadOnly));
        assert_eq!(
            read_only,
            get("AccessType") == Some("ro"),
            "[{name}]: {written:?}"
        );
        checked.push(address);
    }
    // 5E00h:00..05, 5E01h, 4 × 7 entry sub-indices, 5EFEh, 5EFFh.
    assert_eq!(
        checked.len(),
        6 + 1 + 7 * usize::from(ENTRIES) + 2,
        "{checked:?}"
    );
    let beyond = client
        .read(3, Address::new(0x5E10 + u16::from(ENTRIES), 1))
        .expect_err("no fifth entry");
    assert_eq!(
        beyond.sdo_client_error(),
        Some(ClientError::Aborted(AbortCode::NoObject)),
        "{beyond}"
    );
    // The SRDO device's EDS does not list them: that node does not serve them.
    assert!(!eds::eds().contains("[5E00]"));
}
