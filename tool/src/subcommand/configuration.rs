//! The subcommands on nodes' safety configuration: `configure`, `verify`, `set-secret` and
//! `audit`.

use super::BusClient;
use crate::{Person, Unlock, json, load};
use safety_config::ToolError;
use safety_config::access::{self, NEW_SECRET_VARIABLE, SecretSource};
use safety_config::procedure::{self, NodeResult, Verdict};

/// `safety-config configure FILE`: configures, reads back, signs, validates and stores every
/// node of the file, then starts them with `start` when every one was configured; `false`
/// (failure) when a node was not configured.
pub(crate) fn configure(
    client: &mut BusClient,
    file: &str,
    start: bool,
    accept_identity: bool,
    unlock: &Unlock,
    as_json: bool,
) -> Result<bool, ToolError> {
    let network = load(file)?;
    client.sdo_timeout = network.sdo_timeout;
    let mut person = Person {
        accept_identity,
        quiet: as_json,
        secret: unlock.source(),
    };
    let report = procedure::configure(client, &network, start, &mut person)?;
    if as_json {
        println!("{}", json(&report)?);
    } else {
        if let Some(lss) = &report.lss {
            for node in &lss.assigned {
                println!(
                    "node {}: {} given node-ID {} by LSS, stored; it booted on it",
                    node.node_id, node.identity, node.node_id
                );
            }
            for identity in &lss.unknown {
                println!("LSS: not in the network file, left unconfigured: {identity}");
            }
            for (identity, node_id) in &lss.duplicates {
                println!(
                    "LSS: matches node {node_id} of the file, whose node-ID another node took: \
                     {identity}; left unconfigured (pin the revision in the file)"
                );
            }
        }
        for result in &report.nodes {
            match result {
                NodeResult::Done(done) => println!(
                    "node {}: configured and valid; signatures {}",
                    done.node,
                    done.signatures_in_words()
                ),
                NodeResult::Failed { node, error } => {
                    println!("node {node}: NOT configured: {error}")
                }
            }
        }
        if report.started {
            println!("all nodes started");
        } else if start {
            println!("no node was started, because not every node was configured");
        }
    }
    Ok(report.success())
}

/// `safety-config verify FILE`: reads every node's safety configuration and compares it
/// with the file; `false` (failure) unless every node matches and is valid.
pub(crate) fn verify(client: &mut BusClient, file: &str, as_json: bool) -> Result<bool, ToolError> {
    let network = load(file)?;
    client.sdo_timeout = network.sdo_timeout;
    let verdicts = procedure::verify(client, &network)?;
    if as_json {
        println!("{}", json(&verdicts)?);
    } else {
        for verdict in &verdicts {
            match verdict {
                Verdict::Matches { node } => {
                    println!("node {node}: matches the file, valid (0x13FE = A5h)")
                }
                Verdict::Differs { node, diff } => {
                    println!("node {node}: DIFFERS from the file (file vs node):");
                    for line in diff {
                        println!("  {line}");
                    }
                }
                Verdict::NotValidated {
                    node,
                    configuration_valid,
                } => println!(
                    "node {node}: matches the file but is NOT validated (0x13FE = {configuration_valid:02X}h)"
                ),
                Verdict::SimpleCanNotValidated {
                    node,
                    configuration_valid,
                } => println!(
                    "node {node}: matches the file but its SimpleCAN configuration is NOT validated (0x5EFE = {configuration_valid:02X}h)"
                ),
                Verdict::Unreachable { node, error } => {
                    println!("node {node}: not verified: {error}")
                }
            }
        }
    }
    Ok(verdicts
        .iter()
        .all(|verdict| matches!(verdict, Verdict::Matches { .. })))
}

/// `safety-config set-secret NODE`: unlocks the node when asked, then sets and stores its new
/// secret.
pub(crate) fn set_secret(
    client: &mut BusClient,
    node: u8,
    unlock: &Unlock,
    new_secret_file: Option<&std::path::Path>,
    as_json: bool,
) -> Result<bool, ToolError> {
    let mut person = Person {
        accept_identity: false,
        quiet: as_json,
        secret: unlock.source(),
    };
    procedure::unlock_for_configuration(client, node, &mut person)?;
    let new = SecretSource::choose(new_secret_file, NEW_SECRET_VARIABLE)
        .read_new(&format!("new secret of node {node}"))?;
    access::set_secret(client, node, &new)?;
    if as_json {
        println!(
            "{}",
            json(&serde_json::json!({"node": node, "secret_set": true}))?
        );
    } else {
        println!("node {node}: secret set and stored");
    }
    Ok(true)
}

/// `safety-config audit NODE`: the node's access state and audit record.
pub(crate) fn audit(client: &mut BusClient, node: u8, as_json: bool) -> Result<bool, ToolError> {
    #[derive(serde::Serialize)]
    struct Audit<'a, A> {
        state: String,
        audit: &'a A,
    }
    let state = access::state(client, node)?;
    let audit = access::read_audit(client, node)?;
    if as_json {
        println!(
            "{}",
            json(&Audit {
                state: format!("{state:?}"),
                audit: &audit,
            })?
        );
    } else {
        let list = |signatures: &[u16]| {
            signatures
                .iter()
                .zip(1..)
                .map(|(s, n)| format!("SRDO {n} {s:04X}h"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        println!(
            "node {node}: access {state:?}; {} validated change(s)",
            audit.changes
        );
        println!("  before the last: {}", list(&audit.before));
        println!("  after the last:  {}", list(&audit.after));
    }
    Ok(true)
}
