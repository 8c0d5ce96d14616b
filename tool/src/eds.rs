//! The node's electronic data sheet (EDS, CiA 306) and device configuration files (DCF),
//! generated from the device description the firmware is built from
//! (`safety_device`: application objects, identity, heartbeat, SRDO count, bit rate)
//! and the object dictionary the protocol core serves (`shared::node`: communication objects,
//! 0x1300..0x13FF, the double-reception counters 5C00h).
//!
//! The safety keys of CiA 306 Annex A: `[DeviceInfo] CANopenSafetySupported=1`,
//! `SRDOMapping=1` on every object an SRDO may map, and `InvertedSRAD` on each plain object,
//! naming its inverted copy (`0xIIIISS`: index and sub-index in hexadecimal).
//!
//! The committed `eds/safety-node.eds` is [`eds`]'s output; a test fails when they differ.

use shared::canopen::od::Address;
use shared::node::DOUBLE_RECEPTION_INDEX;
use shared::node::access::{
    ACCESS_INDEX, CHANGE_COUNTER_INDEX, SIGNATURES_AFTER_INDEX, SIGNATURES_BEFORE_INDEX,
};
use shared::process_image::{Access, Mappable};
use shared::safety::config::{MAX_MAPPING_ENTRIES, TRANSMISSION_TYPE};
use shared::safety::gfc::GFC_PARAMETER;
use std::collections::BTreeMap;
use std::fmt::Write as _;

mod simplecan;

/// CiA 301 data types used here.
const UNSIGNED8: u16 = 0x0005;
const UNSIGNED16: u16 = 0x0006;
const UNSIGNED32: u16 = 0x0007;
const VISIBLE_STRING: u16 = 0x0009;
const OCTET_STRING: u16 = 0x000A;

/// One value of the dictionary (a VAR, or one sub-index of an ARRAY or RECORD).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Where it is.
    pub address: Address,
    /// `ParameterName`.
    pub name: String,
    /// `DataType` (CiA 301 7.4.7.1).
    pub data_type: u16,
    /// `AccessType`: `ro`, `rw` or `const`.
    pub access: &'static str,
    /// `DefaultValue`, where the device's default does not depend on the node-ID.
    pub default: Option<String>,
    /// `LowLimit` and `HighLimit`, where the node refuses values outside them.
    pub limits: Option<(u32, u32)>,
    /// `SRDOMapping=1` (CiA 306 Annex A): an SRDO may map it.
    pub srdo_mapping: bool,
    /// `InvertedSRAD` (CiA 306 Annex A): its inverted copy.
    pub inverted: Option<Address>,
}

impl Entry {
    fn new(address: Address, name: &str, data_type: u16, access: &'static str) -> Self {
        Entry {
            address,
            name: name.to_owned(),
            data_type,
            access,
            default: None,
            limits: None,
            srdo_mapping: false,
            inverted: None,
        }
    }

    fn default(mut self, value: impl std::fmt::Display) -> Self {
        self.default = Some(value.to_string());
        self
    }

    fn limits(mut self, low: u32, high: u32) -> Self {
        self.limits = Some((low, high));
        self
    }
}

/// One object of the dictionary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Object {
    /// Its index.
    pub index: u16,
    /// `ParameterName`.
    pub name: String,
    /// `0x7` VAR, `0x8` ARRAY, `0x9` RECORD (CiA 301 7.4.3).
    pub object_type: u8,
    /// Its values: one for a VAR (sub-index 0), sub-index 0 first otherwise.
    pub entries: Vec<Entry>,
}

fn var(index: u16, name: &str, data_type: u16, access: &'static str) -> (Object, Entry) {
    (
        Object {
            index,
            name: name.to_owned(),
            object_type: 0x7,
            entries: Vec::new(),
        },
        Entry::new(Address::new(index, 0), name, data_type, access),
    )
}

fn single(index: u16, name: &str, data_type: u16, access: &'static str) -> Object {
    let (mut object, entry) = var(index, name, data_type, access);
    object.entries.push(entry);
    object
}

fn compound(index: u16, name: &str, object_type: u8, highest: u8, access: &'static str) -> Object {
    Object {
        index,
        name: name.to_owned(),
        object_type,
        entries: vec![
            Entry::new(
                Address::new(index, 0),
                "Highest sub-index supported",
                UNSIGNED8,
                access,
            )
            .default(highest),
        ],
    }
}

/// The note on 0x1300 (`shared::safety::gfc::GFC_PARAMETER`): what it means on this device.
pub const GFC_NOTE: [&str; 5] = [
    "1300h (GFC parameter) indicates, as EN 50325-5 6.4.2.1 is written: the device sets it to 1 when it sent or received a GFC in Operational. Writing 0 clears the indication; writing 1 is accepted and does nothing (no GFC is sent); above 1 is refused (0609 0031h).",
    "Stacks that read 1300h as 'GFC enabled' and send a GFC when 1 is written get no GFC from this device: configuring it never trips the bus. The device always obeys a received GFC in Operational.",
    "SRDO 1 follows the pre-defined connection set when nothing is stored (EN 50325-5 Table 5): transmit for node-IDs 1..32 (refresh time 25 ms), receive for 33..64 (SCT 50 ms), deleted for 65..127; COB-IDs FFh + 2 x node-ID and 100h + 2 x node-ID; its default values therefore depend on the node-ID and are not given here.",
    "Safety objects are read-only in Operational (0800 0022h); any accepted write to one sets 13FEh to 0. 1301h..1304h sub-index 04h is fixed at FEh.",
    "Once a secret is set (5C10h:02h), writes to 1010h, 1011h and 1301h..13FFh need an unlock with it (5C10h:01h), refused with 0601 0000h otherwise; 5C11h..5C13h are the audit record of validated changes (docs/access-protection.md).",
];

/// Node-ID 1, checked when the crate is compiled (a `panic!` in a constant is a compile error).
const NODE_1: shared::canopen::NodeId = match shared::canopen::NodeId::new(1) {
    Ok(id) => id,
    Err(_) => panic!("1 is a node-ID"),
};

/// The device description of node 1 (its node-independent parts are the EDS's).
fn description() -> shared::node::NodeConfig {
    safety_device::config(NODE_1, safety_device::CHANNEL_A_NAME)
}

/// The CANopen Safety device's object dictionary (the shipped images: the device's
/// [`SRDO_COUNT`](safety_device::SRDO_COUNT) SRDOs), in index order.
pub fn objects() -> Vec<Object> {
    let srdos = safety_device::SRDO_COUNT as u8;
    let signatures = (1..=srdos).map(|n| format!("SRDO {n}")).collect();
    srdo_device_objects(srdos, signatures)
}

/// The object dictionary of a device with `srdos` SRDOs whose audit records (5C12h, 5C13h)
/// hold one signature per name of `audit_names` (the protocol's signatures, in its order).
fn srdo_device_objects(srdos: u8, audit_names: Vec<String>) -> Vec<Object> {
    use safety_device as device;
    let description = description();
    let hex32 = |value: u32| format!("0x{value:08X}");
    let mut objects = Vec::new();
    let mut device_type = single(0x1000, "Device type", UNSIGNED32, "ro");
    device_type.entries[0].default = Some(hex32(description.device_type));
    objects.push(device_type);
    let mut error_register = single(0x1001, "Error register", UNSIGNED8, "ro");
    error_register.entries[0].default = Some("0".into());
    objects.push(error_register);
    let mut name = single(0x1008, "Manufacturer device name", VISIBLE_STRING, "ro");
    name.entries[0].default = Some(description.device_name.to_owned());
    objects.push(name);
    for (index, what) in [
        (0x1010, ("Store parameters", "Save all parameters")),
        (
            0x1011,
            (
                "Restore default parameters",
                "Restore all default parameters",
            ),
        ),
    ] {
        let mut object = compound(index, what.0, 0x8, 1, "ro");
        object
            .entries
            .push(Entry::new(Address::new(index, 1), what.1, UNSIGNED32, "rw").default(hex32(1)));
        objects.push(object);
    }
    let mut heartbeat = single(0x1017, "Producer heartbeat time", UNSIGNED16, "rw");
    heartbeat.entries[0].default = Some(description.heartbeat_ms.to_string());
    objects.push(heartbeat);
    let mut identity = compound(0x1018, "Identity object", 0x9, 4, "ro");
    for (sub, field) in (1u8..).zip(["Vendor-ID", "Product code", "Revision number"]) {
        identity.entries.push(
            Entry::new(Address::new(0x1018, sub), field, UNSIGNED32, "ro")
                .default(hex32(description.identity[usize::from(sub) - 1])),
        );
    }
    // The serial number is the node-ID on this device (`safety_device::config`).
    identity.entries.push(
        Entry::new(Address::new(0x1018, 4), "Serial number", UNSIGNED32, "ro").default("$NODEID+0"),
    );
    objects.push(identity);
    let mut gfc = single(GFC_PARAMETER, "GFC parameter", UNSIGNED8, "rw");
    gfc.entries[0].default = Some("0".into());
    gfc.entries[0].limits = Some((0, 1));
    objects.push(gfc);
    let count = srdos;
    for n in 1..=count {
        let index = 0x1300 + u16::from(n);
        let first = n == 1;
        let mut object = compound(
            index,
            &format!("SRDO {n} communication parameter"),
            0x9,
            6,
            "ro",
        );
        let address = |sub| Address::new(index, sub);
        let mut direction =
            Entry::new(address(1), "Information direction", UNSIGNED8, "rw").limits(0, 2);
        let mut cycle = Entry::new(address(2), "Refresh time / SCT", UNSIGNED16, "rw");
        let srvt = Entry::new(address(3), "SRVT", UNSIGNED8, "rw").default(20);
        let transmission =
            Entry::new(address(4), "Transmission type", UNSIGNED8, "ro").default(TRANSMISSION_TYPE);
        let mut cob_id_1 = Entry::new(address(5), "COB-ID 1", UNSIGNED32, "rw");
        let mut cob_id_2 = Entry::new(address(6), "COB-ID 2", UNSIGNED32, "rw");
        if !first {
            direction = direction.default(0);
            cycle = cycle.default(25);
            cob_id_1 = cob_id_1.default(hex32(0));
            cob_id_2 = cob_id_2.default(hex32(0));
        }
        object
            .entries
            .extend([direction, cycle, srvt, transmission, cob_id_1, cob_id_2]);
        objects.push(object);
    }
    for n in 1..=count {
        let index = 0x1380 + u16::from(n);
        let mut object = compound(
            index,
            &format!("SRDO {n} mapping parameter"),
            0x9,
            MAX_MAPPING_ENTRIES as u8,
            "rw",
        );
        object.entries[0].name = "Number of mapped objects".into();
        object.entries[0].limits = Some((0, MAX_MAPPING_ENTRIES as u32));
        if n == 1 {
            object.entries[0].default = None;
        } else {
            object.entries[0].default = Some("0".into());
        }
        for sub in 1..=MAX_MAPPING_ENTRIES as u8 {
            let what = if sub % 2 == 1 { "plain" } else { "inverted" };
            let mut entry = Entry::new(
                Address::new(index, sub),
                &format!("Mapping entry {sub} ({what})"),
                UNSIGNED32,
                "rw",
            );
            let predefined = description
                .default_transmit_mapping
                .len()
                .max(description.default_receive_mapping.len());
            if n != 1 || usize::from(sub) > predefined {
                entry = entry.default(hex32(0));
            }
            object.entries.push(entry);
        }
        objects.push(object);
    }
    let mut valid = single(0x13FE, "Configuration valid", UNSIGNED8, "rw");
    valid.entries[0].default = Some("0".into());
    objects.push(valid);
    let mut signatures = compound(0x13FF, "Safety configuration signature", 0x8, count, "ro");
    for n in 1..=count {
        signatures.entries.push(
            Entry::new(
                Address::new(0x13FF, n),
                &format!("Signature of SRDO {n}"),
                UNSIGNED16,
                "rw",
            )
            .default(0),
        );
    }
    objects.push(signatures);
    let mut double = compound(DOUBLE_RECEPTION_INDEX, "CAN double reception", 0x9, 2, "ro");
    for (sub, what) in (1u8..).zip([
        "Repeated plain frames discarded",
        "Inverted frames without plain frame discarded",
    ]) {
        double.entries.push(
            Entry::new(
                Address::new(DOUBLE_RECEPTION_INDEX, sub),
                what,
                UNSIGNED32,
                "ro",
            )
            .default(0),
        );
    }
    objects.push(double);
    let mut access = compound(ACCESS_INDEX, "Configuration access", 0x9, 5, "ro");
    access.entries.extend([
        Entry::new(Address::new(ACCESS_INDEX, 1), "Unlock", OCTET_STRING, "wo"),
        Entry::new(
            Address::new(ACCESS_INDEX, 2),
            "Set secret",
            OCTET_STRING,
            "wo",
        ),
        Entry::new(
            Address::new(ACCESS_INDEX, 3),
            "Access state",
            UNSIGNED8,
            "rw",
        ),
        Entry::new(
            Address::new(ACCESS_INDEX, 4),
            "Failed unlock attempts",
            UNSIGNED16,
            "ro",
        )
        .default(0),
        Entry::new(
            Address::new(ACCESS_INDEX, 5),
            "Remaining unlock or lockout time (ms)",
            UNSIGNED32,
            "ro",
        )
        .default(0),
    ]);
    objects.push(access);
    let mut changes = single(
        CHANGE_COUNTER_INDEX,
        "Validated configuration changes",
        UNSIGNED32,
        "ro",
    );
    changes.entries[0].default = Some("0".into());
    objects.push(changes);
    for (index, when) in [
        (SIGNATURES_BEFORE_INDEX, "before"),
        (SIGNATURES_AFTER_INDEX, "after"),
    ] {
        // At most 2 × 32 + 2 signatures (`shared::node::persist::MAX_SIGNATURES`): fits a u8.
        let mut audit = compound(
            index,
            &format!("Signatures {when} the last validated change"),
            0x8,
            audit_names.len() as u8,
            "ro",
        );
        for (sub, of) in (1u8..).zip(&audit_names) {
            audit.entries.push(
                Entry::new(
                    Address::new(index, sub),
                    &format!("Signature of {of} {when} the last validated change"),
                    UNSIGNED16,
                    "ro",
                )
                .default(0),
            );
        }
        objects.push(audit);
    }
    let mut by_index: BTreeMap<u16, Vec<&shared::process_image::AppObject>> = BTreeMap::new();
    for object in device::OBJECTS.iter() {
        by_index
            .entry(object.address.index)
            .or_default()
            .push(object);
    }
    for (index, subs) in by_index {
        let name = |address: Address| {
            device::OBJECT_NAMES
                .iter()
                .find(|(_, named)| *named == address)
                .map_or_else(|| format!("{index:04X}h"), |(name, _)| (*name).to_owned())
        };
        let highest = subs.iter().map(|o| o.address.sub).max().unwrap_or(0);
        let mut object = compound(index, &name(Address::new(index, 1)), 0x8, highest, "ro");
        for app in subs {
            let data_type = match app.len {
                1 => UNSIGNED8,
                2 => UNSIGNED16,
                _ => UNSIGNED32,
            };
            let access = match app.access {
                Access::ReadOnly => "ro",
                Access::ReadWrite => "rw",
            };
            let mut entry = Entry::new(app.address, &name(app.address), data_type, access);
            entry.srdo_mapping = matches!(app.mappable, Mappable::Transmit | Mappable::Receive);
            entry.inverted = device::INVERTED_PAIRS
                .iter()
                .find(|(plain, _)| *plain == app.address)
                .map(|(_, inverted)| *inverted);
            object.entries.push(entry);
        }
        objects.push(object);
    }
    objects
}

/// The `[index]`/`[indexsubN]` section name of `entry` in `object`.
fn section(object: &Object, entry: &Entry) -> String {
    if object.object_type == 0x7 {
        format!("{:04X}", object.index)
    } else {
        format!("{:04X}sub{:X}", object.index, entry.address.sub)
    }
}

fn write_entry(text: &mut String, object: &Object, entry: &Entry, value: Option<&str>) {
    let _ = writeln!(text, "[{}]", section(object, entry));
    let _ = writeln!(text, "ParameterName={}", entry.name);
    let _ = writeln!(text, "ObjectType=0x7");
    let _ = writeln!(text, "DataType=0x{:04X}", entry.data_type);
    let _ = writeln!(text, "AccessType={}", entry.access);
    if let Some((low, high)) = entry.limits {
        let _ = writeln!(text, "LowLimit={low}");
        let _ = writeln!(text, "HighLimit={high}");
    }
    if let Some(default) = &entry.default {
        let _ = writeln!(text, "DefaultValue={default}");
    }
    if let Some(value) = value {
        let _ = writeln!(text, "ParameterValue={value}");
    }
    let _ = writeln!(text, "PDOMapping=0");
    if entry.srdo_mapping {
        let _ = writeln!(text, "SRDOMapping=1");
    }
    if let Some(inverted) = entry.inverted {
        let _ = writeln!(
            text,
            "InvertedSRAD=0x{:04X}{:02X}",
            inverted.index, inverted.sub
        );
    }
    text.push('\n');
}

/// What a DCF adds to the EDS: the node it is for, and the values read from it.
pub struct Commissioning<'a> {
    /// The node-ID.
    pub node: u8,
    /// A name for the node (the network file's), if any.
    pub name: Option<&'a str>,
    /// The value of every entry read from the node, as the DCF writes it.
    pub values: &'a BTreeMap<Address, String>,
}

/// The DCF of a node whose dictionary is `objects` (`procedure::dictionary_of`).
pub fn dcf(objects: &[Object], commissioning: &Commissioning<'_>) -> String {
    render_objects(
        objects,
        "safety-node.eds",
        "eds",
        Some(commissioning),
        safety_device::LSS_BIT_RATES,
    )
}

/// The dictionary of a device that serves SimpleCAN with `entries` SDD entries beside `srdos`
/// SRDOs (`shared::node::SrdoAndSimpleCan`): the SRDO device's objects for `srdos` and
/// 5E00h..5EFFh (`docs/simplecan.md` section 11), in index order. Its audit records hold
/// `2 R` signatures: the SRDOs', SimpleCAN's CRC-32 as two halves, then unused ones (0),
/// with `R` = `srdos` from 2 SRDOs on (`SimpleCanNode`) and 1 without SRDOs (the firmware
/// images with SimpleCAN, `board::Protocol`). `None` for one SRDO: no such device is built.
pub fn simplecan_objects(entries: u8, srdos: u8) -> Option<Vec<Object>> {
    let rows = match srdos {
        0 => 1,
        1 => return None,
        n => n,
    };
    let mut signatures: Vec<String> = (1..=srdos).map(|n| format!("SRDO {n}")).collect();
    signatures.push("SimpleCAN (5EFFh bits 0..15)".into());
    signatures.push("SimpleCAN (5EFFh bits 16..31)".into());
    while signatures.len() < 2 * usize::from(rows) {
        signatures.push(format!("unused {}", signatures.len() + 1));
    }
    let mut all = srdo_device_objects(srdos, signatures);
    all.extend(simplecan::objects(entries));
    all.sort_by_key(|object| object.index);
    Some(all)
}

/// The EDS of a device that serves SimpleCAN with `entries` SDD entries beside `srdos` SRDOs
/// ([`simplecan_objects`]; `None` for one SRDO). The firmware images with SimpleCAN are
/// [`SIMPLECAN_IMAGES`]'s.
pub fn simplecan_eds(entries: u8, srdos: u8) -> Option<String> {
    Some(render_objects(
        &simplecan_objects(entries, srdos)?,
        "safety-node-simplecan.eds",
        &format!("eds --simplecan {entries} --srdos {srdos}"),
        None,
        safety_device::SIMPLECAN_LSS_BIT_RATES,
    ))
}

/// The SDD entries and SRDOs of the firmware images with SimpleCAN (`board::SIMPLECAN_ENTRIES`,
/// `board::SRDOS`): SimpleCAN instead of SRDOs. Their EDS is the committed
/// `eds/safety-node-simplecan.eds`.
pub const SIMPLECAN_IMAGES: (u8, u8) = (2, 0);

/// The EDS (or with `commissioning` the DCF) of `objects`, named `eds_name`, which the
/// tool's command `regenerate` prints, for a device that runs at the `bit_rates` LSS may
/// configure (its `BaudRate_` entries, CiA 306).
fn render_objects(
    objects: &[Object],
    eds_name: &str,
    regenerate: &str,
    commissioning: Option<&Commissioning<'_>>,
    bit_rates: shared::canopen::lss::BitRates,
) -> String {
    use safety_device as device;
    let description = description();
    let mut text = String::new();
    let file_name = match commissioning {
        Some(commissioning) => format!("node-{}.dcf", commissioning.node),
        None => eds_name.to_owned(),
    };
    let _ = write!(
        text,
        "; Generated by safety-config from the device description (safety_device) and\n\
         ; the protocol core's object dictionary (shared::node). Do not edit: regenerate with\n\
         ; `cargo run -p safety-config -- {regenerate} > eds/{eds_name}`.\n\n\
         [FileInfo]\nFileName={file_name}\nFileVersion=1\nFileRevision=0\nEDSVersion=4.0\n\
         Description=Dual-channel CANopen Safety node (EN 50325-5, CiA 304 Model III)\n\
         CreatedBy=safety-config {}\n\n",
        env!("CARGO_PKG_VERSION")
    );
    let rates_kbit = [10, 20, 50, 125, 250, 500, 800, 1000];
    let _ = writeln!(
        text,
        "[DeviceInfo]\nVendorName=Dual-channel safety node project\nVendorNumber=0x{:08X}\n\
         ProductName=Dual-channel CANopen Safety node\nProductNumber=0x{:08X}\n\
         RevisionNumber=0x{:08X}\nOrderCode=safety-node",
        description.identity[0], description.identity[1], description.identity[2]
    );
    // The rates LSS may configure are the device's (CiA 306: BaudRate_x supported).
    for rate in rates_kbit {
        let supported = u32::from(shared::canopen::lss::BitRate::ALL.into_iter().any(|entry| {
            entry.bits_per_second() == Some(rate * 1000) && bit_rates.contains(entry)
        }));
        let _ = writeln!(text, "BaudRate_{rate}={supported}");
    }
    let _ = write!(
        text,
        "SimpleBootUpMaster=0\nSimpleBootUpSlave=1\nGranularity=0\nDynamicChannelsSupported=0\n\
         GroupMessaging=0\nNrOfRXPDO=0\nNrOfTXPDO=0\nLSS_Supported=1\nCANopenSafetySupported=1\n\n"
    );
    if let Some(commissioning) = commissioning {
        let _ = write!(
            text,
            "[DeviceComissioning]\nNodeID={}\nNodeName={}\nBaudrate={}\nNetNumber=0\nCANopenManager=0\n\n",
            commissioning.node,
            commissioning.name.unwrap_or(""),
            device::BIT_RATE / 1000
        );
    }
    let _ = writeln!(text, "[DummyUsage]");
    for dummy in 1..=7 {
        let _ = writeln!(text, "Dummy{dummy:04}=0");
    }
    let _ = writeln!(text, "\n[Comments]\nLines={}", GFC_NOTE.len());
    for (line, note) in (1..).zip(GFC_NOTE) {
        let _ = writeln!(text, "Line{line}={note}");
    }
    text.push('\n');
    /// An object list of CiA 306 4.5.2 and which indices belong in it.
    type List = (&'static str, fn(u16) -> bool);
    let lists: [List; 3] = [
        ("MandatoryObjects", |index| {
            matches!(index, 0x1000 | 0x1001 | 0x1018)
        }),
        ("OptionalObjects", |index| {
            !matches!(index, 0x1000 | 0x1001 | 0x1018 | 0x2000..=0x5FFF)
        }),
        ("ManufacturerObjects", |index| {
            matches!(index, 0x2000..=0x5FFF)
        }),
    ];
    for (list, member) in lists {
        let indices: Vec<u16> = objects
            .iter()
            .map(|o| o.index)
            .filter(|i| member(*i))
            .collect();
        let _ = writeln!(text, "[{list}]\nSupportedObjects={}", indices.len());
        for (n, index) in (1..).zip(&indices) {
            let _ = writeln!(text, "{n}=0x{index:04X}");
        }
        text.push('\n');
    }
    let value = |address: Address| {
        commissioning
            .and_then(|commissioning| commissioning.values.get(&address).map(String::as_str))
    };
    for object in objects {
        if object.object_type == 0x7 {
            write_entry(
                &mut text,
                object,
                &object.entries[0],
                value(object.entries[0].address),
            );
            continue;
        }
        let _ = write!(
            text,
            "[{:04X}]\nParameterName={}\nObjectType=0x{:X}\nSubNumber=0x{:X}\n\n",
            object.index,
            object.name,
            object.object_type,
            object.entries.len()
        );
        for entry in &object.entries {
            write_entry(&mut text, object, entry, value(entry.address));
        }
    }
    text
}

/// The CANopen Safety node's EDS (CiA 306 4.0 syntax).
pub fn eds() -> String {
    render_objects(
        &objects(),
        "safety-node.eds",
        "eds",
        None,
        safety_device::LSS_BIT_RATES,
    )
}

/// The text a DCF gives a value of `entry` read as `bytes` (little-endian integers as
/// hexadecimal, strings as they are).
pub fn format_value(entry: &Entry, bytes: &[u8]) -> String {
    if entry.data_type == VISIBLE_STRING {
        return String::from_utf8_lossy(bytes).into_owned();
    }
    let mut raw = [0u8; 4];
    let len = bytes.len().min(4);
    raw[..len].copy_from_slice(&bytes[..len]);
    let value = u32::from_le_bytes(raw);
    match entry.data_type {
        UNSIGNED8 => format!("0x{value:02X}"),
        UNSIGNED16 => format!("0x{value:04X}"),
        _ => format!("0x{value:08X}"),
    }
}

/// The CiA 301 name of a data type this EDS uses (7.4.7.1), `None` for another.
pub fn type_name(data_type: u16) -> Option<&'static str> {
    match data_type {
        UNSIGNED8 => Some("UNSIGNED8"),
        UNSIGNED16 => Some("UNSIGNED16"),
        UNSIGNED32 => Some("UNSIGNED32"),
        VISIBLE_STRING => Some("VISIBLE_STRING"),
        OCTET_STRING => Some("OCTET_STRING"),
        _ => None,
    }
}

/// The octets of an unsigned data type, `None` for a type of another length or kind.
fn unsigned_length(data_type: u16) -> Option<usize> {
    match data_type {
        UNSIGNED8 => Some(1),
        UNSIGNED16 => Some(2),
        UNSIGNED32 => Some(4),
        _ => None,
    }
}

/// The entry at `address` in the dictionary of a device this tool generates the EDS of: the
/// CANopen Safety device's ([`objects`]), else the largest device with SimpleCAN
/// ([`simplecan_objects`] with every SDD entry and SRDO it can have), whose objects are the
/// same with 5E00h..5EFFh added. `None`: no device of this project has it.
pub fn entry_at(address: Address) -> Option<Entry> {
    let find = |objects: Vec<Object>| {
        objects
            .into_iter()
            .flat_map(|object| object.entries)
            .find(|entry| entry.address == address)
    };
    find(objects()).or_else(|| {
        let most_entries = shared::simplecan::sdd::MAX_ENTRIES as u8;
        find(simplecan_objects(most_entries, 4)?)
    })
}

/// A value read from `entry` in words, by its EDS type: an unsigned number as the type, then
/// hexadecimal with every digit of the type and decimal (`UNSIGNED32 0x00000123 (291)`);
/// a VISIBLE_STRING as quoted text; an OCTET_STRING as its octets. A number of another
/// length than its type's is shown as octets with the lengths named, never as a number.
pub fn describe_value(entry: &Entry, bytes: &[u8]) -> String {
    let octets = || {
        bytes
            .iter()
            .map(|byte| format!("{byte:02X}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let name = type_name(entry.data_type).unwrap_or("an unknown type");
    match entry.data_type {
        VISIBLE_STRING => format!("{name} {:?}", String::from_utf8_lossy(bytes)),
        OCTET_STRING => format!("{name} {} ({} bytes)", octets(), bytes.len()),
        data_type => match unsigned_length(data_type) {
            Some(length) if length == bytes.len() => {
                let mut raw = [0u8; 4];
                raw[..length].copy_from_slice(bytes);
                let value = u32::from_le_bytes(raw);
                format!("{name} 0x{value:0width$X} ({value})", width = 2 * length)
            }
            Some(length) => format!(
                "{} byte(s) where {name} has {length}: {}",
                bytes.len(),
                octets()
            ),
            None => format!("{name} (data type {data_type:04X}h): {}", octets()),
        },
    }
}

/// A value read from `entry` for JSON: an unsigned number of its type's length as a number,
/// a VISIBLE_STRING as text, anything else `None` (the octets say it).
pub fn json_value(entry: &Entry, bytes: &[u8]) -> Option<serde_json::Value> {
    if entry.data_type == VISIBLE_STRING {
        return Some(String::from_utf8_lossy(bytes).into_owned().into());
    }
    let length = unsigned_length(entry.data_type).filter(|length| *length == bytes.len())?;
    let mut raw = [0u8; 4];
    raw[..length].copy_from_slice(bytes);
    Some(u32::from_le_bytes(raw).into())
}
