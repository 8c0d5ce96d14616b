//! The network file (TOML): which nodes the network has, who they must be, and their SRDOs.
//!
//! ```toml
//! [bus]
//! sdo_timeout_ms = 500          # optional
//! lss_fastscan = true           # optional: `configure` first gives every unconfigured node
//!                               # (node-ID FFh) the node-ID below for its identity by LSS
//!                               # fastscan (CiA 305), stored, and waits for its boot-up
//!
//! [[node]]
//! id = 1
//! name = "emergency stop"       # optional, for messages
//! identity = { vendor = 0xABC, product = 0x304, serial = 1 }   # revision optional
//! clear_gfc_indication = true   # optional: write 0 to 0x1300 while configuring
//!
//! [[node.srdo]]
//! number = 1
//! direction = "transmit"        # or "receive"
//! refresh_time_ms = 25          # transmit; a receive SRDO gives sct_ms
//! srvt_ms = 20                  # required for receive; transmit default 20 (Table 5)
//! cob_ids = [0x101, 0x102]
//! mapping = ["input", "0x6001:1:8"]   # a name of the device description or index:sub:bits
//! ```
//!
//! A SimpleCAN network adds a `[simplecan]` section and a `[node.simplecan]` table per node
//! (`network_file::simplecan`, its format and rules; `docs/tool.md`).
//!
//! Every error comes back as a [`FileError`] with line, column and a sentence. SRDOs of a node
//! that the file does not list are deleted (direction 0) by `configure`.

use crate::signature::SrdoSettings;
use serde::Deserialize;
use shared::canopen::od::Address;
use shared::process_image::Mappable;
use shared::safety::config::ConfigError;
use shared::safety::types::CobIdPair;
use std::time::Duration;
use toml::Spanned;

mod simplecan;

/// A mistake in the network file, where it is.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error, serde::Serialize)]
#[error("{origin}:{line}:{column}: {message}")]
pub struct FileError {
    /// The file's name (or `<text>`).
    pub origin: String,
    /// Line, from 1.
    pub line: usize,
    /// Column, from 1 (characters).
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

/// The identity a node must have (0x1018).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Identity {
    /// Vendor-ID (sub-index 1).
    pub vendor: u32,
    /// Product code (sub-index 2).
    pub product: u32,
    /// Revision number (sub-index 3), when the file pins it.
    pub revision: Option<u32>,
    /// Serial number (sub-index 4).
    pub serial: u32,
}

/// One SRDO as the file wants it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SrdoSpec {
    /// SRDO number 1..=64 (0x1300 + n, 0x1380 + n, 0x13FF sub-index n).
    pub number: u8,
    /// Its parameters.
    pub settings: SrdoSettings,
}

/// One node as the file wants it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct NodeSpec {
    /// Node-ID 1..=127.
    pub id: u8,
    /// A name for messages.
    pub name: Option<String>,
    /// Who it must be.
    pub identity: Identity,
    /// Its SRDOs, by number.
    pub srdos: Vec<SrdoSpec>,
    /// Whether `configure` clears the GFC indication (0x1300 = 0).
    pub clear_gfc_indication: bool,
}

/// The whole network.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Network {
    /// How long one SDO request waits for its answer.
    #[serde(serialize_with = "millis")]
    pub sdo_timeout: Duration,
    /// The nodes, in file order.
    pub nodes: Vec<NodeSpec>,
    /// `configure` starts with an LSS fastscan (CiA 305) that gives every unconfigured node
    /// the node-ID of its identity in this file, stored (`[bus] lss_fastscan = true`).
    pub lss_fastscan: bool,
    /// The SimpleCAN part (`[simplecan]` and each `[node.simplecan]`), when the file has one
    /// ([`crate::simplecan`]); without it `configure` leaves the SimpleCAN objects alone.
    pub simplecan: Option<crate::simplecan::SimpleCanNetwork>,
}

fn millis<S: serde::Serializer>(duration: &Duration, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_u64(duration.as_millis() as u64)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    bus: RawBus,
    #[serde(default)]
    node: Vec<Spanned<RawNode>>,
    simplecan: Option<Spanned<simplecan::RawSimpleCan>>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawBus {
    sdo_timeout_ms: Option<Spanned<i64>>,
    #[serde(default)]
    lss_fastscan: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNode {
    id: Spanned<i64>,
    name: Option<String>,
    identity: RawIdentity,
    #[serde(default)]
    clear_gfc_indication: bool,
    #[serde(default)]
    srdo: Vec<Spanned<RawSrdo>>,
    simplecan: Option<Spanned<simplecan::RawNodeSimpleCan>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIdentity {
    vendor: Spanned<i64>,
    product: Spanned<i64>,
    revision: Option<Spanned<i64>>,
    serial: Spanned<i64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSrdo {
    number: Spanned<i64>,
    direction: Spanned<String>,
    refresh_time_ms: Option<Spanned<i64>>,
    sct_ms: Option<Spanned<i64>>,
    srvt_ms: Option<Spanned<i64>>,
    cob_ids: Spanned<Vec<Spanned<i64>>>,
    mapping: Spanned<Vec<Spanned<String>>>,
}

/// Line and column (from 1, in characters) of byte `offset` in `text`.
fn position(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |at| at + 1);
    (line, before[line_start..].chars().count() + 1)
}

struct Parser<'a> {
    text: &'a str,
    origin: &'a str,
}

impl Parser<'_> {
    fn error(&self, span: std::ops::Range<usize>, message: impl Into<String>) -> FileError {
        let (line, column) = position(self.text, span.start);
        FileError {
            origin: self.origin.to_owned(),
            line,
            column,
            message: message.into(),
        }
    }

    /// `value` as a number in `range`, or the error naming `what`.
    fn number<T: TryFrom<i64>>(
        &self,
        value: &Spanned<i64>,
        range: std::ops::RangeInclusive<i64>,
        what: &str,
    ) -> Result<T, FileError> {
        let raw = *value.get_ref();
        if !range.contains(&raw) {
            return Err(self.error(
                value.span(),
                format!(
                    "{what} is {raw}, but must be {} to {}",
                    range.start(),
                    range.end()
                ),
            ));
        }
        T::try_from(raw).map_err(|_| self.error(value.span(), format!("{what} is out of range")))
    }
}

/// Parses a network file; `origin` names it in errors.
pub fn parse(text: &str, origin: &str) -> Result<Network, FileError> {
    let parser = Parser { text, origin };
    let raw: RawFile = toml::from_str(text).map_err(|error| {
        let span = error.span().unwrap_or(0..0);
        parser.error(span, error.message().trim_end().to_owned())
    })?;
    let sdo_timeout = match &raw.bus.sdo_timeout_ms {
        Some(value) => {
            Duration::from_millis(parser.number(value, 1..=60_000, "the SDO timeout (ms)")?)
        }
        None => Duration::from_millis(500),
    };
    if raw.node.is_empty() {
        return Err(parser.error(0..0, "the file names no node: add a [[node]] table"));
    }
    let mut nodes: Vec<NodeSpec> = Vec::new();
    for node in &raw.node {
        let spec = node_spec(&parser, node.get_ref())?;
        if nodes.iter().any(|other| other.id == spec.id) {
            return Err(parser.error(
                node.get_ref().id.span(),
                format!("node-ID {} is given to two nodes", spec.id),
            ));
        }
        nodes.push(spec);
    }
    let simplecan = simplecan::parse(&parser, raw.simplecan.as_ref(), &raw.node, &nodes)?;
    Ok(Network {
        sdo_timeout,
        nodes,
        lss_fastscan: raw.bus.lss_fastscan,
        simplecan,
    })
}

const U32: std::ops::RangeInclusive<i64> = 0..=0xFFFF_FFFF;

fn node_spec(parser: &Parser<'_>, node: &RawNode) -> Result<NodeSpec, FileError> {
    let id: u8 = parser.number(&node.id, 1..=127, "the node-ID")?;
    let identity = Identity {
        vendor: parser.number(&node.identity.vendor, U32, "the vendor-ID")?,
        product: parser.number(&node.identity.product, U32, "the product code")?,
        revision: node
            .identity
            .revision
            .as_ref()
            .map(|value| parser.number(value, U32, "the revision number"))
            .transpose()?,
        serial: parser.number(&node.identity.serial, U32, "the serial number")?,
    };
    let mut srdos: Vec<SrdoSpec> = Vec::new();
    for srdo in &node.srdo {
        let spec = srdo_spec(parser, srdo.get_ref())?;
        if srdos.iter().any(|other| other.number == spec.number) {
            return Err(parser.error(
                srdo.get_ref().number.span(),
                format!("node {id}: SRDO {} is listed twice", spec.number),
            ));
        }
        srdos.push(spec);
    }
    for pair in srdos
        .iter()
        .enumerate()
        .flat_map(|(i, a)| srdos[i + 1..].iter().map(move |b| (a, b)))
    {
        let (a, b) = pair;
        if a.settings.cob_id_1 == b.settings.cob_id_1 {
            let later = node
                .srdo
                .iter()
                .find(|raw| *raw.get_ref().number.get_ref() == i64::from(b.number));
            let span = later.map_or(0..0, |raw| raw.get_ref().cob_ids.span());
            return Err(parser.error(
                span,
                format!(
                    "node {id}: SRDO {} uses the COB-IDs of SRDO {} (EN 50325-5 7.2.1: each SRDO has its own)",
                    b.number, a.number
                ),
            ));
        }
    }
    Ok(NodeSpec {
        id,
        name: node.name.clone(),
        identity,
        srdos,
        clear_gfc_indication: node.clear_gfc_indication,
    })
}

/// A sentence for the COB-ID rules of EN 50325-5 7.2.1 that `error` breaks.
fn cob_id_sentence(error: ConfigError) -> &'static str {
    match error {
        ConfigError::CobIdTooLow => "COB-IDs of SRDOs start at 101h (EN 50325-5 7.2.1)",
        ConfigError::CobIdTooHigh => "COB-IDs of SRDOs end at 180h (EN 50325-5 7.2.1)",
        ConfigError::CobIdParity => {
            "the first COB-ID must be odd and the second even (EN 50325-5 7.2.1)"
        }
        ConfigError::CobIdsNotConsecutive => {
            "the second COB-ID must be the first plus one (EN 50325-5 7.2.1)"
        }
        _ => "these COB-IDs are not an SRDO pair (EN 50325-5 7.2.1)",
    }
}

fn srdo_spec(parser: &Parser<'_>, srdo: &RawSrdo) -> Result<SrdoSpec, FileError> {
    let number: u8 = parser.number(&srdo.number, 1..=64, "the SRDO number")?;
    let (direction, wanted) = match srdo.direction.get_ref().as_str() {
        "transmit" => (1u8, Mappable::Transmit),
        "receive" => (2u8, Mappable::Receive),
        other => {
            return Err(parser.error(
                srdo.direction.span(),
                format!("SRDO {number}: the direction is {other:?}, but must be \"transmit\" or \"receive\""),
            ));
        }
    };
    let cycle_time: u16 = match (direction, &srdo.refresh_time_ms, &srdo.sct_ms) {
        (1, Some(value), None) => parser.number(value, 1..=65535, "the refresh time (ms)")?,
        (2, None, Some(value)) => parser.number(value, 1..=65535, "the SCT (ms)")?,
        (1, _, Some(value)) => {
            return Err(parser.error(value.span(), format!("SRDO {number} transmits: give refresh_time_ms, not sct_ms (SCT is a receive SRDO's)")));
        }
        (_, Some(value), _) => {
            return Err(parser.error(value.span(), format!("SRDO {number} receives: give sct_ms, not refresh_time_ms (a refresh time is a transmit SRDO's)")));
        }
        _ => {
            let needed = if direction == 1 {
                "refresh_time_ms"
            } else {
                "sct_ms"
            };
            return Err(parser.error(
                srdo.number.span(),
                format!("SRDO {number}: {needed} is missing"),
            ));
        }
    };
    let srvt: u8 = match &srdo.srvt_ms {
        Some(value) => parser.number(value, 1..=255, "the SRVT (ms)")?,
        None if direction == 1 => 20,
        None => {
            return Err(parser.error(
                srdo.number.span(),
                format!("SRDO {number} receives: srvt_ms is missing"),
            ));
        }
    };
    if let (2, Some(value)) = (direction, &srdo.srvt_ms) {
        if u16::from(srvt) >= cycle_time {
            return Err(parser.error(
                value.span(),
                format!("SRDO {number}: the SRVT ({srvt} ms) must be shorter than the SCT ({cycle_time} ms)"),
            ));
        }
    }
    let ids = srdo.cob_ids.get_ref();
    if ids.len() != 2 {
        return Err(parser.error(
            srdo.cob_ids.span(),
            format!(
                "SRDO {number}: cob_ids needs two identifiers (plain, inverted), not {}",
                ids.len()
            ),
        ));
    }
    let cob_id_1: u32 = parser.number(&ids[0], 0..=0x7FF, "COB-ID 1")?;
    let cob_id_2: u32 = parser.number(&ids[1], 0..=0x7FF, "COB-ID 2")?;
    if let Err(error) = CobIdPair::new(cob_id_1, cob_id_2) {
        return Err(parser.error(
            srdo.cob_ids.span(),
            format!(
                "SRDO {number}: COB-IDs {cob_id_1:X}h and {cob_id_2:X}h: {}",
                cob_id_sentence(error)
            ),
        ));
    }
    let entries = srdo.mapping.get_ref();
    if entries.is_empty() || entries.len() % 2 != 0 || entries.len() > 16 {
        return Err(parser.error(
            srdo.mapping.span(),
            format!(
                "SRDO {number}: the mapping has {} entries, but needs 2 to 16, in pairs (plain, inverted; EN 50325-5 6.4.1.3)",
                entries.len()
            ),
        ));
    }
    let mapping = entries
        .iter()
        .map(|entry| mapping_entry(parser, &format!("SRDO {number}"), entry, wanted))
        .collect::<Result<Vec<u32>, FileError>>()?;
    Ok(SrdoSpec {
        number,
        settings: SrdoSettings {
            direction,
            cycle_time,
            srvt,
            cob_id_1,
            cob_id_2,
            mapping,
        },
    })
}

/// A mapping entry: a name from the device description, or `index:sub:bits`, mappable in
/// direction `wanted`; `label` names what maps it in messages (`SRDO 1`, `node 1: SC-ID 30h`).
fn mapping_entry(
    parser: &Parser<'_>,
    label: &str,
    entry: &Spanned<String>,
    wanted: Mappable,
) -> Result<u32, FileError> {
    let text = entry.get_ref().trim();
    let names = || {
        safety_device::OBJECT_NAMES
            .iter()
            .map(|(name, _)| *name)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (address, bits) = if let Some((_, address)) = safety_device::OBJECT_NAMES
        .iter()
        .find(|(name, _)| *name == text)
    {
        let object = safety_device::OBJECTS
            .iter()
            .find(|object| object.address == *address);
        (
            *address,
            object.map_or(8, |object| u32::from(object.len) * 8),
        )
    } else {
        let parts: Vec<&str> = text.split(':').collect();
        let parse = |part: &str| {
            let part = part.trim();
            match part.strip_prefix("0x").or_else(|| part.strip_prefix("0X")) {
                Some(hex) => u32::from_str_radix(hex, 16).ok(),
                None => part.parse().ok(),
            }
        };
        match parts.as_slice() {
            [index, sub, bits] => match (parse(index), parse(sub), parse(bits)) {
                (Some(index @ 0..=0xFFFF), Some(sub @ 0..=0xFF), Some(bits @ 1..=64)) => {
                    (Address::new(index as u16, sub as u8), bits)
                }
                _ => {
                    return Err(parser.error(
                        entry.span(),
                        format!("{label}: {text:?} is not index:sub:bits (e.g. 0x6000:1:8)"),
                    ));
                }
            },
            _ => {
                return Err(parser.error(
                    entry.span(),
                    format!("{label}: {text:?} is neither an object name ({}) nor index:sub:bits (e.g. 0x6000:1:8)", names()),
                ));
            }
        }
    };
    // The device description says what may be mapped in which direction.
    match safety_device::OBJECTS
        .iter()
        .find(|object| object.address == address)
    {
        Some(object) if object.mappable == wanted => {
            if bits != u32::from(object.len) * 8 {
                return Err(parser.error(
                    entry.span(),
                    format!(
                        "{label}: object {:04X}h:{:02X}h has {} bits, not {bits}",
                        address.index,
                        address.sub,
                        u32::from(object.len) * 8
                    ),
                ));
            }
        }
        Some(_) => {
            let direction = if wanted == Mappable::Transmit {
                "a transmit SRDO or a produced SC-ID"
            } else {
                "a receive SRDO or a consumed SC-ID"
            };
            return Err(parser.error(
                entry.span(),
                format!("{label}: object {:04X}h:{:02X}h cannot be mapped into {direction} of this device", address.index, address.sub),
            ));
        }
        None => {
            return Err(parser.error(
                entry.span(),
                format!(
                    "{label}: the device has no mappable object {:04X}h:{:02X}h",
                    address.index, address.sub
                ),
            ));
        }
    }
    Ok(u32::from(address.index) << 16 | u32::from(address.sub) << 8 | bits)
}

/// The byte range of the value of `key` in section `[section]` of an INI text (for error
/// positions), or of the section header when the key is missing, or `0..0`.
fn ini_span(text: &str, section: &str, key: &str) -> std::ops::Range<usize> {
    let mut offset = 0;
    let mut inside = false;
    let mut header = None;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim();
        if trimmed.starts_with('[') {
            inside = trimmed
                .trim_start_matches('[')
                .trim_end_matches(']')
                .eq_ignore_ascii_case(section);
            if inside {
                header = Some(offset..offset + trimmed.len());
            }
        } else if inside {
            if let Some((name, value)) = line.split_once('=') {
                if name.trim().eq_ignore_ascii_case(key) {
                    let start = offset + name.len() + 1;
                    return start..start + value.trim_end().len();
                }
            }
        }
        offset += line.len();
    }
    header.unwrap_or(0..0)
}

/// Parses a device configuration file (DCF, CiA 306) of one node, as the tool exports it
/// (`safety-config dcf`), into a network of that node: its node-ID (`[DeviceComissioning]
/// NodeID`), its identity (1018h, serial number included) and every SRDO whose direction is
/// not 0, from the `ParameterValue`s. The SRDOs pass the checks of a network file (with
/// positions in the DCF), and each one's signature in 13FFh must be the one its values give
/// (the tool's own CRC): a DCF whose values and signatures disagree is not the record of
/// one configuration, and is refused. So is the DCF of a node with SimpleCAN (sections
/// 5E00h..5EFFh): its SimpleCAN configuration would not be taken, and a network file's
/// `[simplecan]` section is where it comes from.
pub fn parse_dcf(text: &str, origin: &str) -> Result<Network, FileError> {
    let parser = Parser { text, origin };
    let ini = ini::Ini::load_from_str(text).map_err(|error| FileError {
        origin: origin.to_owned(),
        line: error.line.max(1),
        column: error.col.max(1),
        message: format!("this is not an INI (CiA 306) file: {}", error.msg),
    })?;
    let find = |section: &str, key: &str| {
        ini.iter()
            .find(|(name, _)| name.is_some_and(|name| name.eq_ignore_ascii_case(section)))
            .and_then(|(_, properties)| {
                properties
                    .iter()
                    .find(|(name, _)| name.eq_ignore_ascii_case(key))
                    .map(|(_, value)| value.trim().to_owned())
            })
    };
    let number = |section: &str, key: &str| -> Result<Spanned<i64>, FileError> {
        let span = ini_span(text, section, key);
        let value = find(section, key).ok_or_else(|| {
            parser.error(
                span.clone(),
                format!("[{section}] has no {key}: a DCF of a configured node has one"),
            )
        })?;
        let parsed = match value
            .strip_prefix("0x")
            .or_else(|| value.strip_prefix("0X"))
        {
            Some(hex) => i64::from_str_radix(hex, 16),
            None => value.parse(),
        };
        parsed
            .map(|raw| Spanned::new(span.clone(), raw))
            .map_err(|_| {
                parser.error(
                    span,
                    format!("[{section}] {key} is {value:?}, not a number"),
                )
            })
    };
    let value = |section: String| number(&section, "ParameterValue");
    if let Some(section) = ini
        .sections()
        .flatten()
        .find(|name| name.len() >= 4 && name[..2].eq_ignore_ascii_case("5E"))
    {
        return Err(parser.error(
            ini_span(text, section, "ParameterValue"),
            format!(
                "[{section}] is a SimpleCAN object: this is the DCF of a node with SimpleCAN, \
                 whose configuration a DCF does not carry to `configure` or `verify`; \
                 configure it from a network file's [simplecan] section"
            ),
        ));
    }
    let id: u8 = parser.number(
        &number("DeviceComissioning", "NodeID")?,
        1..=127,
        "the node-ID",
    )?;
    let identity = Identity {
        vendor: parser.number(&value("1018sub1".into())?, U32, "the vendor-ID")?,
        product: parser.number(&value("1018sub2".into())?, U32, "the product code")?,
        revision: Some(parser.number(&value("1018sub3".into())?, U32, "the revision number")?),
        serial: parser.number(&value("1018sub4".into())?, U32, "the serial number")?,
    };
    let name = find("DeviceComissioning", "NodeName").filter(|name| !name.is_empty());
    let mut srdos = Vec::new();
    for n in 1..=64u16 {
        let comm = 0x1300 + n;
        if find(&format!("{comm:04X}sub1"), "ParameterValue").is_none() {
            break;
        }
        let direction = value(format!("{comm:04X}sub1"))?;
        let label = match *direction.get_ref() {
            0 => continue,
            1 => "transmit",
            2 => "receive",
            other => {
                return Err(parser.error(
                    direction.span(),
                    format!("SRDO {n}: the information direction is {other}, not 0, 1 or 2"),
                ));
            }
        };
        let cycle = value(format!("{comm:04X}sub2"))?;
        let (refresh_time_ms, sct_ms) = if label == "transmit" {
            (Some(cycle), None)
        } else {
            (None, Some(cycle))
        };
        let cob_1 = value(format!("{comm:04X}sub5"))?;
        let cob_2 = value(format!("{comm:04X}sub6"))?;
        let cob_span = cob_1.span().start..cob_2.span().end.max(cob_1.span().end);
        let map = 0x1380 + n;
        let count = value(format!("{map:04X}sub0"))?;
        let count: u8 = parser.number(&count, 0..=16, "the number of mapped objects")?;
        let mut mapping = Vec::new();
        for sub in 1..=count {
            let entry = value(format!("{map:04X}sub{sub:X}"))?;
            let raw: u32 = parser.number(&entry, U32, &format!("SRDO {n} mapping entry {sub}"))?;
            mapping.push(Spanned::new(
                entry.span(),
                format!("0x{:04X}:{}:{}", raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF),
            ));
        }
        let map_span = ini_span(text, &format!("{map:04X}sub0"), "ParameterValue");
        let raw = RawSrdo {
            number: Spanned::new(direction.span(), i64::from(n)),
            direction: Spanned::new(direction.span(), label.to_owned()),
            refresh_time_ms,
            sct_ms,
            srvt_ms: Some(value(format!("{comm:04X}sub3"))?),
            cob_ids: Spanned::new(cob_span, vec![cob_1, cob_2]),
            mapping: Spanned::new(map_span, mapping),
        };
        let spec = srdo_spec(&parser, &raw)?;
        let stored = value(format!("13FFsub{n:X}"))?;
        let computed = crate::signature::signature(&spec.settings);
        if *stored.get_ref() != i64::from(computed) {
            return Err(parser.error(
                stored.span(),
                format!(
                    "SRDO {n}: the signature is {:04X}h, but these values give {computed:04X}h (EN 50325-5 6.4.1.5): the DCF is not the record of one validated configuration",
                    stored.get_ref()
                ),
            ));
        }
        srdos.push(spec);
    }
    Ok(Network {
        sdo_timeout: Duration::from_millis(500),
        nodes: vec![NodeSpec {
            id,
            name,
            identity,
            srdos,
            clear_gfc_indication: false,
        }],
        lss_fastscan: false,
        simplecan: None,
    })
}
