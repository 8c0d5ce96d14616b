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
use shared::node::access::SIGNATURES_AFTER_INDEX;
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
    let name = safety_device::CHANNEL_A_NAME;
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

/// What an EDS text lists against what a node serves, over any SDO path (`read`, `write`
/// give the abort code of a refused transfer): every entry (each `ObjectType=0x7` section)
/// answers with its data type's length and, where the EDS gives one, its default value
/// (`$NODEID+0`: `node`); a read-only entry refuses a write with 0601 0002h and a write-only
/// one a read with 0601 0001h; and no object it does not list answers in `probed`. A
/// record's or an array's highest sub-index is an entry with its default like any other, so
/// an EDS that lists another number of sub-entries than the node serves fails there. Returns
/// the entries checked.
fn eds_lists_exactly_what_the_node_serves(
    text: &str,
    node: u8,
    mut read: impl FnMut(Address) -> Result<Vec<u8>, AbortCode>,
    mut write: impl FnMut(Address, &[u8]) -> Result<(), AbortCode>,
    probed: impl IntoIterator<Item = u16>,
) -> Vec<Address> {
    let sections = sections(text);
    let mut listed = std::collections::BTreeSet::new();
    let mut checked = Vec::new();
    for (name, keys) in &sections {
        let get = |key: &str| {
            keys.iter()
                .find(|(k, _)| k == key)
                .map(|(_, value)| value.as_str())
        };
        let (index, sub) = name.split_once("sub").unwrap_or((name.as_str(), "0"));
        let (Ok(index), Ok(sub)) = (u16::from_str_radix(index, 16), u8::from_str_radix(sub, 16))
        else {
            continue;
        };
        listed.insert(index);
        if get("ObjectType") != Some("0x7") {
            continue;
        }
        let address = Address::new(index, sub);
        if get("AccessType") == Some("wo") {
            assert_eq!(read(address), Err(AbortCode::WriteOnly), "[{name}]");
            checked.push(address);
            continue;
        }
        let bytes = read(address).unwrap_or_else(|code| panic!("[{name}]: {code:?}"));
        let data_type =
            u16::from_str_radix(get("DataType").unwrap().trim_start_matches("0x"), 16).unwrap();
        if let Some(len) = length(data_type) {
            assert_eq!(bytes.len(), len, "[{name}]");
        }
        if let Some(default) = get("DefaultValue") {
            let expected = if default == "$NODEID+0" {
                Some(u64::from(node))
            } else if let Some(hex) = default.strip_prefix("0x") {
                Some(u64::from_str_radix(hex, 16).unwrap())
            } else {
                default.parse::<u64>().ok()
            };
            match expected {
                Some(expected) => {
                    let mut raw = [0u8; 8];
                    raw[..bytes.len()].copy_from_slice(&bytes);
                    assert_eq!(u64::from_le_bytes(raw), expected, "[{name}]");
                }
                None => assert_eq!(String::from_utf8_lossy(&bytes), default, "[{name}]"),
            }
        }
        let written = write(address, &bytes).err();
        assert_eq!(
            written == Some(AbortCode::ReadOnly),
            get("AccessType") == Some("ro"),
            "[{name}]: {written:?}"
        );
        checked.push(address);
    }
    for index in probed.into_iter().filter(|index| !listed.contains(index)) {
        assert_eq!(
            read(Address::new(index, 0)),
            Err(AbortCode::NoObject),
            "{index:04X}h, which the EDS does not list"
        );
    }
    checked
}

/// The abort code of a transfer the client saw refused (any other error fails the test).
fn abort_code(error: safety_config::error::ToolError) -> AbortCode {
    match error.sdo_client_error() {
        Some(shared::canopen::sdo_client::ClientError::Aborted(code)) => code,
        _ => panic!("not an abort: {error}"),
    }
}

/// The ranges probed for objects an EDS does not list: communication, the manufacturer
/// objects the node uses (5C00h.., SimpleCAN's 5E00h..5EFFh) and the profile's.
fn probed() -> impl Iterator<Item = u16> {
    (0x1000..=0x1FFF)
        .chain(0x5C00..=0x5C1F)
        .chain(0x5E00..=0x5EFF)
        .chain(0x6000..=0x62FF)
}

/// The EDS of a node that speaks SimpleCAN beside the host simulations' 4 SRDOs with 4 SDD
/// entries (`safety-config eds --simplecan 4`), parsed from its text, against such a node
/// over the simulated bus: the whole dictionary, SimpleCAN's objects 5E00h..5EFFh and the
/// audit records of its 8 signatures included (`eds_lists_exactly_what_the_node_serves`);
/// the entry after its last SDD entry is 0602 0000h. The SRDO device's EDS does not list
/// 5E00h: that node does not serve it.
#[test]
fn sc_req_16_the_simplecan_eds_lists_exactly_what_the_node_serves() {
    use system_tests::simplecan_net::ScNetwork;
    // ScDevice holds 4 SRDOs and 4 SDD entries.
    const ENTRIES: u8 = 4;
    let mut net = ScNetwork::new(500_000, &[3]);
    net.run_for(Duration::from_millis(10));
    let client = std::cell::RefCell::new(Client::new(
        SimulatedBus::new(net),
        StdDuration::from_millis(200),
    ));
    let text = eds::simplecan_eds(ENTRIES, 4).unwrap();
    // Left for third-party readers (python-canopen's `import_od`).
    let kept = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("safety-node-simplecan.eds");
    std::fs::write(&kept, &text).unwrap_or_else(|error| panic!("{}: {error}", kept.display()));
    let checked = eds_lists_exactly_what_the_node_serves(
        &text,
        3,
        |address| client.borrow_mut().read(3, address).map_err(abort_code),
        |address, bytes| {
            client
                .borrow_mut()
                .write(3, address, bytes)
                .map_err(abort_code)
        },
        probed(),
    );
    let simplecan = checked
        .iter()
        .filter(|a| a.index >= 0x5E00 && a.index <= 0x5EFF);
    // 5E00h:00..05, 5E01h, 4 × 7 entry sub-indices, 5EFEh, 5EFFh.
    assert_eq!(simplecan.count(), 6 + 1 + 7 * usize::from(ENTRIES) + 2);
    let audit = checked.iter().filter(|a| a.index == SIGNATURES_AFTER_INDEX);
    assert_eq!(audit.count(), 1 + 8, "2 R = 8 signatures for 4 SRDOs");
    let beyond = client
        .borrow_mut()
        .read(3, Address::new(0x5E10 + u16::from(ENTRIES), 1))
        .map_err(abort_code);
    assert_eq!(beyond, Err(AbortCode::NoObject));
    assert!(!eds::eds().contains("[5E00]"));
    assert_eq!(
        eds::simplecan_eds(ENTRIES, 1),
        None,
        "no node has 1 SRDO and SimpleCAN"
    );

    // The DCF of such a node is read along the dictionary it serves: SimpleCAN's objects
    // with its 4 entries, and the audit records of its 8 signatures.
    let client = &mut *client.borrow_mut();
    let dictionary = procedure::dictionary_of(client, 3).unwrap();
    assert_eq!(dictionary, eds::simplecan_objects(ENTRIES, 4).unwrap());
    let dcf = procedure::read_dcf(client, 3, Some("SimpleCAN")).unwrap();
    for section in [
        "[5E00sub4]",
        "[5E13sub6]",
        "[5EFF]",
        "[5C13sub8]",
        "[1304sub1]",
    ] {
        assert!(dcf.contains(section), "{section} in the DCF");
    }
    assert!(!dcf.contains("[5E14"));
    // Taken as a file, it is refused at its first SimpleCAN object: `configure` would not
    // carry SimpleCAN's configuration from it.
    let error = network_file::parse_dcf(&dcf, "node-3.dcf").unwrap_err();
    let first = dcf[..dcf.find("[5E00]").unwrap()].matches('\n').count() + 1;
    assert!(
        error.message.contains("SimpleCAN object") && error.line == first,
        "{error} (5E00h at line {first})"
    );
}

/// The committed EDS of the firmware images with SimpleCAN (`eds/safety-node-simplecan.eds`:
/// SimpleCAN instead of SRDOs, 2 SDD entries) is the tool's, and lists exactly what their
/// protocol core serves (`board::Protocol`: `SrdoAndSimpleCan<0, 2, 1>`, node 33): no SRDO
/// objects, 13FFh with no signatures, audit records of SimpleCAN's 2 signature halves, and
/// SimpleCAN's objects with 2 entries.
#[test]
fn sc_req_16_the_simplecan_images_eds_lists_exactly_what_their_node_serves() {
    use shared::canopen::NodeId;
    use shared::canopen::sdo_client;
    use shared::canopen::storage::RamFlash;
    use shared::node::{Device, Event, Sink, SrdoAndSimpleCan};
    use shared::{CanFrame, CanId, Instant};
    type Images = SrdoAndSimpleCan<0, 2, 1>;
    assert_eq!(
        eds::SIMPLECAN_IMAGES,
        (board::SIMPLECAN_ENTRIES as u8, board::SRDOS as u8),
        "the images' counts are the board's (built with the feature simplecan)"
    );
    let (entries, srdos) = eds::SIMPLECAN_IMAGES;
    let text = eds::simplecan_eds(entries, srdos).unwrap();
    let committed = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../eds/safety-node-simplecan.eds"
    ))
    .expect("eds/safety-node-simplecan.eds is committed");
    assert!(
        committed == text,
        "eds/safety-node-simplecan.eds differs from the generated EDS: regenerate it with \
         `cargo run -p safety-config -- eds --simplecan {entries} --srdos {srdos} > \
         eds/safety-node-simplecan.eds`"
    );

    /// The node's SDO responses.
    #[derive(Default)]
    struct Responses(Vec<CanFrame>);
    impl Sink for Responses {
        fn transmit(&mut self, frame: CanFrame) {
            self.0.push(frame);
        }
        fn event(&mut self, _: Event) {}
    }
    const NODE: u8 = 33;
    let config = safety_device::config(NodeId::new(NODE).unwrap(), safety_device::CHANNEL_A_NAME);
    let protocol = Images::new(&config).unwrap();
    let node = std::cell::RefCell::new(
        Device::with_protocol(config, RamFlash::<8192>::new(), protocol).unwrap(),
    );
    node.borrow_mut()
        .poll(Instant::ZERO, &mut Responses::default());
    let exchange = |request: [u8; 8]| {
        let frame = CanFrame::new(CanId::new(0x600 + u16::from(NODE)).unwrap(), &request).unwrap();
        let mut responses = Responses::default();
        node.borrow_mut()
            .handle_frame(Instant::ZERO, &frame, &mut responses);
        responses
            .0
            .iter()
            .find(|f| f.id().raw() == 0x580 + u16::from(NODE))
            .map(|f| f.data().try_into().unwrap())
    };
    let aborted = |error| match error {
        sdo_client::ClientError::Aborted(code) => code,
        other => panic!("not an abort: {other:?}"),
    };
    let checked = eds_lists_exactly_what_the_node_serves(
        &text,
        NODE,
        |address| {
            sdo_client::upload(exchange, address)
                .map(|bytes| bytes.to_vec())
                .map_err(aborted)
        },
        |address, bytes| sdo_client::download(exchange, address, bytes).map_err(aborted),
        probed(),
    );
    assert!(!checked.iter().any(|a| (0x1301..=0x13FD).contains(&a.index)));
    assert_eq!(
        checked.iter().filter(|a| a.index == 0x13FF).count(),
        1,
        "13FFh:00 = 0 only"
    );
    let audit = checked.iter().filter(|a| a.index == SIGNATURES_AFTER_INDEX);
    assert_eq!(audit.count(), 1 + 2, "SimpleCAN's signature as two halves");
    let simplecan = checked
        .iter()
        .filter(|a| a.index >= 0x5E00 && a.index <= 0x5EFF);
    assert_eq!(simplecan.count(), 6 + 1 + 7 * usize::from(entries) + 2);
}
