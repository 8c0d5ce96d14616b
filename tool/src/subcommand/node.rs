//! The subcommands on one node or the whole bus: `scan`, `nmt`, `read`, `write`, `dcf`,
//! `gfc` and `lss`.

use super::BusClient;
use crate::{Nmt, Person, Unlock, json, load, parse_object, parse_value, parse_write, read_line};
use safety_config::{ToolError, access, procedure};
use shared::canopen::nmt::NmtCommand;
use std::time::Duration;

/// `safety-config scan`: listens for boot-up and heartbeat messages for `listen_ms`, then
/// reads each node's identity.
pub(crate) fn scan(
    client: &mut BusClient,
    listen_ms: u64,
    as_json: bool,
) -> Result<bool, ToolError> {
    let found = procedure::scan(client, Duration::from_millis(listen_ms))?;
    if as_json {
        println!("{}", json(&found)?);
    } else if found.is_empty() {
        println!("no node sent a boot-up or heartbeat message in {listen_ms} ms");
    } else {
        for node in &found {
            match &node.identity {
                Ok(identity) => {
                    println!("node {:3}: {}, {identity}", node.node, node.state)
                }
                Err(error) => println!(
                    "node {:3}: {}, identity not read: {error}",
                    node.node, node.state
                ),
            }
        }
    }
    Ok(true)
}

/// `safety-config nmt COMMAND TARGET`: sends the NMT command to node `target` (1..=127) or to
/// `all`.
pub(crate) fn nmt(
    client: &mut BusClient,
    command: Nmt,
    target: &str,
    as_json: bool,
) -> Result<bool, ToolError> {
    let node = if target == "all" {
        0
    } else {
        target
            .parse::<u8>()
            .ok()
            .filter(|id| (1..=127).contains(id))
            .ok_or_else(|| {
                ToolError::Usage(format!("{target:?} is not a node-ID 1..=127 or `all`"))
            })?
    };
    let command = match command {
        Nmt::Start => NmtCommand::Start,
        Nmt::Stop => NmtCommand::Stop,
        Nmt::PreOperational => NmtCommand::EnterPreOperational,
        Nmt::ResetNode => NmtCommand::ResetNode,
        Nmt::ResetCommunication => NmtCommand::ResetCommunication,
    };
    client.nmt(command, node)?;
    if as_json {
        println!(
            "{}",
            json(&serde_json::json!({"sent": true, "target": node}))?
        );
    }
    Ok(true)
}

/// `safety-config read NODE OBJECT [SUB]`: reads the object and prints its value as the
/// device's EDS types it.
pub(crate) fn read(
    client: &mut BusClient,
    node: u8,
    object: &str,
    sub: Option<&str>,
    as_json: bool,
) -> Result<bool, ToolError> {
    let address = parse_object(object, sub)?;
    let value = client.read(node, address)?;
    if as_json {
        let entry = safety_config::eds::entry_at(address);
        let data_type = entry
            .as_ref()
            .and_then(|entry| safety_config::eds::type_name(entry.data_type));
        let decoded = entry
            .as_ref()
            .and_then(|entry| safety_config::eds::json_value(entry, &value));
        println!(
            "{}",
            json(
                &serde_json::json!({"node": node, "index": address.index, "sub": address.sub, "bytes": value, "type": data_type, "value": decoded})
            )?
        );
    } else {
        println!("{}", read_line(address, &value));
    }
    Ok(true)
}

/// What `write` is given on the command line.
pub(crate) struct WriteArgs<'a> {
    /// The node-ID.
    pub(crate) node: u8,
    /// The object's index, perhaps with its sub-index.
    pub(crate) object: &'a str,
    /// The sub-index when `object` has none, then the value.
    pub(crate) rest: &'a [String],
    /// Bytes of a numeric value.
    pub(crate) len: usize,
    /// The value as hexadecimal octets.
    pub(crate) bytes: bool,
    /// Whether and how to unlock the node first.
    pub(crate) unlock: &'a Unlock,
}

/// `safety-config write NODE OBJECT [SUB] VALUE`: unlocks the node when asked, then writes
/// the object.
pub(crate) fn write(
    client: &mut BusClient,
    given: &WriteArgs,
    as_json: bool,
) -> Result<bool, ToolError> {
    let node = given.node;
    let (address, value) = parse_write(given.object, given.rest)?;
    let data = parse_value(&value, given.len, given.bytes)?;
    let mut person = Person {
        accept_identity: false,
        quiet: as_json,
        secret: given.unlock.source(),
    };
    procedure::unlock_for_configuration(client, node, &mut person)?;
    client
        .write(node, address, &data)
        .map_err(access::explain_refusal)?;
    if as_json {
        println!(
            "{}",
            json(&serde_json::json!({"node": node, "written": true}))?
        );
    }
    Ok(true)
}

/// `safety-config dcf NODE`: reads the node's whole object dictionary and prints its DCF.
pub(crate) fn dcf(client: &mut BusClient, node: u8, name: Option<&str>) -> Result<bool, ToolError> {
    print!("{}", procedure::read_dcf(client, node, name)?);
    Ok(true)
}

/// `safety-config gfc`: sends the global fail-safe command.
pub(crate) fn gfc(client: &mut BusClient, as_json: bool) -> Result<bool, ToolError> {
    client.transport.send(&shared::safety::gfc::frame())?;
    if as_json {
        println!("{}", json(&serde_json::json!({"sent": "gfc"}))?);
    }
    Ok(true)
}

/// `safety-config lss ACTION`: the Layer Setting Services, each request waiting
/// `lss_timeout_ms` for its answers.
pub(crate) fn lss(
    client: BusClient,
    action: &safety_config::lss::LssCommand,
    lss_timeout_ms: u64,
    as_json: bool,
) -> Result<bool, ToolError> {
    let network = match action {
        safety_config::lss::LssCommand::Fastscan { file, .. } => Some(load(file)?),
        _ => None,
    };
    let timeout = Duration::from_millis(lss_timeout_ms);
    let output = safety_config::lss::run(client.transport, action, network.as_ref(), timeout)?;
    if as_json {
        println!("{}", json(&output.json)?);
    } else {
        print!("{}", output.text);
    }
    Ok(output.complete)
}
