//! What the tool does to nodes: `configure` and `verify` (EN 50325-5 8.3.1), `scan`, and the
//! offline signatures.
//!
//! `configure` writes in the order of EN 50325-5 8.3.1 and never lets a node look valid unless
//! every value it holds was read back, by another path than the write, and equals the file:
//!
//! 1. read the identity (0x1018) and refuse a node that is not the file's (SC_REQ_37/38);
//!    unlock the node with the operator's secret when the operator has one (SC_REQ_43,
//!    [`crate::access`]); a locked node refuses the first write (0601 0000h), and nothing is
//!    written ([`ToolError::Locked`]);
//! 2. NMT enter pre-operational;
//! 3. every SRDO's direction to 0 (deleted, so its parameters may change);
//! 4. the mapping of each SRDO of the file (count 0, entries, count);
//! 5. the communication parameters (refresh time/SCT, SRVT, COB-IDs, direction last);
//! 6. read back every record after all writes, in the reverse order (last SRDO first, each
//!    record's sub-indices from the highest), and compare with the file;
//! 7. compute every signature with the tool's own CRC ([`crate::signature`]), write 0x13FF,
//!    read it back;
//! 8. 0x13FE = A5h, read it back; store (0x1010); read 0x13FE again.
//!
//! Any mismatch or silence stops the node's configuration with an error, and 0x13FE is set to
//! 0 (best effort; every accepted write to a safety object already sets it to 0, EN 50325-5
//! 6.4.1.6, and A5h is only written after every check passed).

use crate::access::{self, Secret};
use crate::client::Client;
use crate::error::{Object, ToolError, object_name};
use crate::network_file::{Identity, Network, NodeSpec};
use crate::signature::{SrdoSettings, signature};
use crate::transport::Transport;
use shared::canopen::nmt::NmtCommand;
use shared::canopen::od::{AbortCode, Address};
use shared::node::access::AccessState;
use shared::safety::config::{CONFIGURATION_VALID, TRANSMISSION_TYPE};
use std::time::Duration;

/// Whoever runs the tool: told what happens, asked when a node is not the file's.
pub trait Operator {
    /// A line of progress for the person.
    fn note(&mut self, line: &str);
    /// Whether to configure `node` although its identity differs (`differences`).
    fn confirm_identity(&mut self, node: &NodeSpec, differences: &str) -> bool;
    /// The secret to unlock `node` with before it is configured (SC_REQ_43), or `None` to
    /// configure without unlocking (a new device; a locked one then refuses).
    fn secret(&mut self, _node: u8) -> Result<Option<Secret>, ToolError> {
        Ok(None)
    }
}

/// An operator that prints nothing and accepts a differing identity only when told to.
pub struct Quiet {
    /// Accept a node whose identity differs from the file (`--accept-identity`).
    pub accept_identity: bool,
}

impl Operator for Quiet {
    fn note(&mut self, _line: &str) {}
    fn confirm_identity(&mut self, _node: &NodeSpec, _differences: &str) -> bool {
        self.accept_identity
    }
}

/// The identity read from a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct NodeIdentity {
    /// Vendor-ID.
    pub vendor: u32,
    /// Product code.
    pub product: u32,
    /// Revision number.
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
}

impl std::fmt::Display for NodeIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "vendor {:08X}h, product {:08X}h, revision {:08X}h, serial {}",
            self.vendor, self.product, self.revision, self.serial
        )
    }
}

/// Reads 0x1018 sub-indices 1 to 4.
pub fn read_identity<T: Transport>(
    client: &mut Client<T>,
    node: u8,
) -> Result<NodeIdentity, ToolError> {
    let mut field = |sub| client.read_unsigned(node, Address::new(0x1018, sub), 4);
    Ok(NodeIdentity {
        vendor: field(1)?,
        product: field(2)?,
        revision: field(3)?,
        serial: field(4)?,
    })
}

/// The fields in which `actual` differs from `expected`, as a sentence; empty when none.
pub fn identity_differences(expected: &Identity, actual: &NodeIdentity) -> String {
    let mut differences = Vec::new();
    let mut compare = |what: &str, file: u32, node: u32| {
        if file != node {
            differences.push(format!("{what}: file {file:X}h, node {node:X}h"));
        }
    };
    compare("vendor-ID", expected.vendor, actual.vendor);
    compare("product code", expected.product, actual.product);
    if let Some(revision) = expected.revision {
        compare("revision", revision, actual.revision);
    }
    compare("serial number", expected.serial, actual.serial);
    differences.join("; ")
}

/// One SRDO record as read from a node.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ReadRecord {
    /// The parameters of Table 9.
    pub settings: SrdoSettings,
    /// Sub-index 04h (not part of the signature; always 254).
    pub transmission_type: u8,
}

/// Reads SRDO `n`'s whole record, every sub-index from the highest down (the reverse of the
/// write order): communication parameters 06h..01h, then the mapping count and its entries
/// from the last.
pub fn read_record<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    n: u8,
) -> Result<ReadRecord, ToolError> {
    let comm = 0x1300 + u16::from(n);
    let map = 0x1380 + u16::from(n);
    let cob_id_2 = client.read_unsigned(node, Address::new(comm, 6), 4)?;
    let cob_id_1 = client.read_unsigned(node, Address::new(comm, 5), 4)?;
    let transmission_type = client.read_unsigned(node, Address::new(comm, 4), 1)? as u8;
    let srvt = client.read_unsigned(node, Address::new(comm, 3), 1)? as u8;
    let cycle_time = client.read_unsigned(node, Address::new(comm, 2), 2)? as u16;
    let direction = client.read_unsigned(node, Address::new(comm, 1), 1)? as u8;
    let count = client.read_unsigned(node, Address::new(map, 0), 1)?.min(16) as u8;
    let mut mapping = vec![0; usize::from(count)];
    for sub in (1..=count).rev() {
        mapping[usize::from(sub) - 1] = client.read_unsigned(node, Address::new(map, sub), 4)?;
    }
    Ok(ReadRecord {
        settings: SrdoSettings {
            direction,
            cycle_time,
            srvt,
            cob_id_1,
            cob_id_2,
            mapping,
        },
        transmission_type,
    })
}

/// The differences between what the file wants for SRDO `n` (`None`: deleted) and what the
/// node holds, one line each: `SRDO 1 COB-ID 1 (1301h:05h): file 101h, node 103h`.
pub fn record_diff(n: u8, wanted: Option<&SrdoSettings>, node: &ReadRecord) -> Vec<String> {
    let comm = 0x1300 + u16::from(n);
    let map = 0x1380 + u16::from(n);
    let mut lines = Vec::new();
    let mut compare = |address: Address, file: u32, held: u32| {
        if file != held {
            lines.push(format!(
                "{} ({:04X}h:{:02X}h): file {file:X}h, node {held:X}h",
                object_name(address).unwrap_or_default(),
                address.index,
                address.sub
            ));
        }
    };
    let held = &node.settings;
    let Some(file) = wanted else {
        compare(Address::new(comm, 1), 0, u32::from(held.direction));
        return lines;
    };
    compare(
        Address::new(comm, 1),
        u32::from(file.direction),
        u32::from(held.direction),
    );
    compare(
        Address::new(comm, 2),
        u32::from(file.cycle_time),
        u32::from(held.cycle_time),
    );
    compare(
        Address::new(comm, 3),
        u32::from(file.srvt),
        u32::from(held.srvt),
    );
    compare(
        Address::new(comm, 4),
        u32::from(TRANSMISSION_TYPE),
        u32::from(node.transmission_type),
    );
    compare(Address::new(comm, 5), file.cob_id_1, held.cob_id_1);
    compare(Address::new(comm, 6), file.cob_id_2, held.cob_id_2);
    compare(
        Address::new(map, 0),
        file.mapping.len() as u32,
        held.mapping.len() as u32,
    );
    for (sub, (file, held)) in (1u8..).zip(file.mapping.iter().zip(&held.mapping)) {
        compare(Address::new(map, sub), *file, *held);
    }
    lines
}

/// What configuring one node did.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Configured {
    /// The node-ID.
    pub node: u8,
    /// The identity it reported.
    pub identity: NodeIdentity,
    /// The signature written for each SRDO (number, value).
    pub signatures: Vec<(u8, u16)>,
    /// The SimpleCAN configuration signature written to 0x5EFF, when the file has a
    /// SimpleCAN section ([`configure_simplecan`]).
    pub simplecan_signature: Option<u32>,
    /// SDO requests this node's configuration took.
    pub sdo_requests: u64,
}

impl Configured {
    /// The signatures written, in words: each SRDO's (or that the node has none), then
    /// SimpleCAN's, if written.
    pub fn signatures_in_words(&self) -> String {
        let srdos = if self.signatures.is_empty() {
            "no SRDOs".to_owned()
        } else {
            self.signatures
                .iter()
                .map(|(n, s)| format!("SRDO {n} {s:04X}h"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match self.simplecan_signature {
            Some(value) => format!("{srdos}; SimpleCAN {value:08X}h (0x5EFF)"),
            None => srdos,
        }
    }
}

/// The number of SRDOs `node` has (0x13FF sub-index 0).
fn srdo_count<T: Transport>(client: &mut Client<T>, node: u8) -> Result<u8, ToolError> {
    Ok(client.read_unsigned(node, Address::new(0x13FF, 0), 1)? as u8)
}

/// Configures one node from its part of the network file (the order is the module's).
pub fn configure_node<T: Transport>(
    client: &mut Client<T>,
    spec: &NodeSpec,
    operator: &mut dyn Operator,
) -> Result<Configured, ToolError> {
    let node = spec.id;
    let before = client.requests;
    let identity = read_identity(client, node)?;
    let label = spec
        .name
        .as_deref()
        .map(|name| format!(" ({name})"))
        .unwrap_or_default();
    operator.note(&format!("node {node}{label}: {identity}"));
    let differences = identity_differences(&spec.identity, &identity);
    if !differences.is_empty() && !operator.confirm_identity(spec, &differences) {
        return Err(ToolError::IdentityMismatch { node, differences });
    }
    unlock_for_configuration(client, node, operator)?;
    client.nmt(NmtCommand::EnterPreOperational, node)?;
    match write_and_check(client, spec, operator) {
        Ok(signatures) => Ok(Configured {
            node,
            identity,
            signatures,
            simplecan_signature: None,
            sdo_requests: client.requests - before,
        }),
        Err(error) => match access::explain_refusal(error) {
            // Locked, or the unlock ended: the node took no write since (and 0x13FE is 0
            // after any write it took before).
            locked @ ToolError::Locked { .. } => Err(locked),
            error => {
                // Best effort: a node that stopped answering cannot be told; every write it
                // accepted has already set 0x13FE to 0.
                if client.write(node, Address::new(0x13FE, 0), &[0]).is_ok() {
                    operator.note(&format!(
                        "node {node}: 0x13FE set to 0 (configuration not valid)"
                    ));
                }
                Err(error)
            }
        },
    }
}

/// Unlocks `node` with the operator's secret, if the operator has one (SC_REQ_43); says so
/// when the node has no secret to unlock with.
pub fn unlock_for_configuration<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    operator: &mut dyn Operator,
) -> Result<(), ToolError> {
    let Some(secret) = operator.secret(node)? else {
        return Ok(());
    };
    match access::state(client, node)? {
        AccessState::Open => operator.note(&format!(
            "node {node}: has no secret (open for configuration); set one with `set-secret`"
        )),
        AccessState::Unlocked | AccessState::Locked | AccessState::LockedOut => {
            access::unlock(client, node, &secret)?;
            operator.note(&format!("node {node}: unlocked for configuration"));
        }
    }
    Ok(())
}

fn write_and_check<T: Transport>(
    client: &mut Client<T>,
    spec: &NodeSpec,
    operator: &mut dyn Operator,
) -> Result<Vec<(u8, u16)>, ToolError> {
    let node = spec.id;
    let count = srdo_count(client, node)?;
    if let Some(extra) = spec.srdos.iter().find(|srdo| srdo.number > count) {
        return Err(ToolError::Usage(format!(
            "node {node} has {count} SRDO(s), but the network file configures SRDO {}",
            extra.number
        )));
    }
    let wanted = |n: u8| {
        spec.srdos
            .iter()
            .find(|srdo| srdo.number == n)
            .map(|srdo| &srdo.settings)
    };
    operator.note(&if count == 0 {
        format!("node {node}: has no SRDOs")
    } else {
        format!("node {node}: deleting SRDOs 1..={count} (direction 0)")
    });
    for n in 1..=count {
        client.write(node, Address::new(0x1300 + u16::from(n), 1), &[0])?;
    }
    if spec.clear_gfc_indication {
        client.write(node, Address::new(0x1300, 0), &[0])?;
    }
    for srdo in &spec.srdos {
        let map = 0x1380 + u16::from(srdo.number);
        client.write(node, Address::new(map, 0), &[0])?;
        for (sub, entry) in (1u8..).zip(&srdo.settings.mapping) {
            client.write(node, Address::new(map, sub), &entry.to_le_bytes())?;
        }
        client.write(
            node,
            Address::new(map, 0),
            &[srdo.settings.mapping.len() as u8],
        )?;
    }
    for srdo in &spec.srdos {
        let comm = 0x1300 + u16::from(srdo.number);
        let settings = &srdo.settings;
        client.write(
            node,
            Address::new(comm, 2),
            &settings.cycle_time.to_le_bytes(),
        )?;
        client.write(node, Address::new(comm, 3), &[settings.srvt])?;
        client.write(
            node,
            Address::new(comm, 5),
            &settings.cob_id_1.to_le_bytes(),
        )?;
        client.write(
            node,
            Address::new(comm, 6),
            &settings.cob_id_2.to_le_bytes(),
        )?;
        client.write(node, Address::new(comm, 1), &[settings.direction])?;
    }
    if count > 0 {
        operator.note(&format!("node {node}: reading every record back"));
    }
    let mut diff = Vec::new();
    let mut signed = Vec::new();
    for n in (1..=count).rev() {
        let held = read_record(client, node, n)?;
        diff.extend(record_diff(n, wanted(n), &held));
        // A deleted SRDO is signed over what it holds; a configured one over the file's values
        // (equal to what it holds when the diff is empty).
        let settings = wanted(n).cloned().unwrap_or(held.settings);
        signed.push((n, signature(&settings)));
    }
    if !diff.is_empty() {
        return Err(ToolError::ReadBackMismatch {
            node,
            diff: diff.join("\n"),
        });
    }
    signed.reverse();
    write_signatures(client, node, &signed)?;
    validate(client, node)?;
    store(client, node)?;
    operator.note(&format!(
        "node {node}: configured, signed, valid and stored"
    ));
    Ok(signed)
}

/// Writes each SRDO's signature to 0x13FF (in SRDO order), then reads them all back (in the
/// reverse order) and compares; a difference is a [`ToolError::ReadBackMismatch`].
pub fn write_signatures<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    signed: &[(u8, u16)],
) -> Result<(), ToolError> {
    for &(n, value) in signed {
        client.write(node, Address::new(0x13FF, n), &value.to_le_bytes())?;
    }
    let mut diff = Vec::new();
    for &(n, value) in signed.iter().rev() {
        let held = client.read_unsigned(node, Address::new(0x13FF, n), 2)? as u16;
        if held != value {
            diff.push(format!(
                "signature of SRDO {n} (13FFh:{n:02X}h): tool {value:04X}h, node {held:04X}h"
            ));
        }
    }
    if diff.is_empty() {
        Ok(())
    } else {
        Err(ToolError::ReadBackMismatch {
            node,
            diff: diff.join("\n"),
        })
    }
}

/// Declares the configuration valid (0x13FE = A5h, EN 50325-5 6.4.1.6) and reads 0x13FE
/// back: a node whose Operational-entry check refuses the configuration aborts the write
/// (0604 0043h) or does not keep A5h.
pub fn validate<T: Transport>(client: &mut Client<T>, node: u8) -> Result<(), ToolError> {
    client.write(node, Address::new(0x13FE, 0), &[CONFIGURATION_VALID])?;
    check_valid(client, node, "writing it")
}

/// Stores the parameters (0x1010:01 = "save", CiA 301 7.5.2.13) and reads 0x13FE again.
pub fn store<T: Transport>(client: &mut Client<T>, node: u8) -> Result<(), ToolError> {
    client
        .write(node, STORE_PARAMETERS, b"save")
        .map_err(explain_store_refusal)?;
    check_valid(client, node, "storing (0x1010)")
}

/// Store parameters, save all (CiA 301 7.5.2.13).
pub const STORE_PARAMETERS: Address = Address::new(0x1010, 1);

/// `error`, or [`ToolError::StoreRefused`] when it is the node's refusal of a store for its
/// state (0800 0022h on 0x1010:01): the sentence then says why and what to do.
pub fn explain_store_refusal(error: ToolError) -> ToolError {
    match error {
        ToolError::Aborted {
            node, object, code, ..
        } if code == AbortCode::DeviceState as u32 && object.0 == STORE_PARAMETERS => {
            ToolError::StoreRefused { node }
        }
        other => other,
    }
}

/// Signs SRDOs `srdos` of `node` over the values they hold: reads each record back whole,
/// computes its signature with the tool's own CRC ([`crate::signature`]), writes and reads
/// back 0x13FF, and declares the configuration valid ([`validate`]). Returns the signatures.
///
/// This signs whatever the node holds, so it is for callers that wrote the parameters
/// themselves and checked them; [`configure_node`] signs the file's values after comparing
/// every record with them.
pub fn sign_and_validate<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    srdos: &[u8],
) -> Result<Vec<(u8, u16)>, ToolError> {
    let mut signed = Vec::with_capacity(srdos.len());
    for &n in srdos {
        let held = read_record(client, node, n)?;
        signed.push((n, signature(&held.settings)));
    }
    write_signatures(client, node, &signed)?;
    validate(client, node)?;
    Ok(signed)
}

fn check_valid<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    when: &'static str,
) -> Result<(), ToolError> {
    let value = client.read_unsigned(node, Address::new(0x13FE, 0), 1)? as u8;
    if value == CONFIGURATION_VALID {
        Ok(())
    } else {
        Err(ToolError::NotValid { node, value, when })
    }
}

/// The outcome of `configure` for each node, in file order.
#[derive(Debug, serde::Serialize)]
pub struct ConfigureReport {
    /// What the LSS fastscan did first, when the file asks for it (`[bus] lss_fastscan`).
    pub lss: Option<crate::lss::FastscanReport>,
    /// Per node: what was done, or the error as a sentence.
    pub nodes: Vec<NodeResult<Configured>>,
    /// Whether the nodes were started.
    pub started: bool,
}

/// One node's result: done, or the error's sentence.
#[derive(Debug, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NodeResult<T> {
    /// It worked.
    Done(T),
    /// It did not; the sentence says why.
    Failed {
        /// The node-ID.
        node: u8,
        /// The error, as a sentence.
        error: String,
    },
}

impl ConfigureReport {
    /// Whether every node was configured.
    pub fn success(&self) -> bool {
        self.nodes
            .iter()
            .all(|result| matches!(result, NodeResult::Done(_)))
    }
}

/// How long each LSS request of [`configure`]'s fastscan waits for its answers: the default
/// of `safety-config lss --lss-timeout-ms`.
pub const LSS_TIMEOUT: std::time::Duration = std::time::Duration::from_millis(100);

/// The LSS fastscan [`configure`] starts with when the file asks for it (`[bus]
/// lss_fastscan`): every unconfigured node (node-ID FFh) is given the node-ID of its identity
/// in the file, stored, and has booted on it when this returns (CiA 305); a node the file does
/// not know stays unconfigured and is named in the report. An LSS error names the node
/// (identity) and the step.
fn lss_first<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
) -> Result<Option<crate::lss::FastscanReport>, ToolError> {
    if !network.lss_fastscan {
        return Ok(None);
    }
    let report = crate::lss::LssMaster::new(&mut client.transport, LSS_TIMEOUT)
        .fastscan_assign(network, true)?;
    Ok(Some(report))
}

/// Configures every node of `network`, after an LSS fastscan when the file asks for one
/// (`[bus] lss_fastscan`); starts them (NMT start, each node) only when `start` is set and every
/// node was configured. A node that fails does not stop the others from being tried, but no
/// node is started then.
pub fn configure<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
    start: bool,
    operator: &mut dyn Operator,
) -> Result<ConfigureReport, ToolError> {
    let lss = lss_first(client, network)?;
    let mut nodes = Vec::new();
    for spec in &network.nodes {
        // A transport failure ends the whole run: the interface is gone for every node.
        nodes.push(configure_one(client, network, spec, operator)?);
    }
    finish_configure(client, network, lss, nodes, start)
}

/// [`configure`] with the nodes side by side: node `i` of the file over `clients[i]`, each on
/// its own thread, so that one node's SDO round trips overlap the others'. CiA 301 7.2.4 lets
/// a client have one transfer at a time with each SDO server; a server is its node's (600h +
/// node-ID, 580h + node-ID), so transfers to different nodes may run at once. Each client
/// sees every frame on the bus and takes only its own node's answers ([`Client`]); for
/// socketcand, each is its own connection, as a socketcand daemon serves several clients on
/// one bus. Each node goes through exactly the steps of [`configure`], in its order; what the
/// operator is told or asked comes from one node at a time. The nodes are started (the first
/// client, one after another) only when every node was configured; a transport failure of
/// any client ends the run with that failure once the others are done.
///
/// Fails with [`ToolError::Usage`] when there are fewer clients than nodes.
pub fn configure_concurrently<T: Transport + Send>(
    clients: &mut [Client<T>],
    network: &Network,
    start: bool,
    operator: &mut (dyn Operator + Send),
) -> Result<ConfigureReport, ToolError> {
    let lss = match clients.first_mut() {
        Some(first) => lss_first(first, network)?,
        None => None,
    };
    let shared = std::sync::Mutex::new(operator);
    let results = side_by_side(clients, network, |client, spec| {
        configure_one(client, network, spec, &mut SharedOperator(&shared))
    })?;
    let nodes = results.into_iter().collect::<Result<Vec<_>, _>>()?;
    let first = clients
        .first_mut()
        .ok_or_else(|| ToolError::Usage("no client to configure the nodes with".into()))?;
    finish_configure(first, network, lss, nodes, start)
}

/// [`verify`] with the nodes side by side, as [`configure_concurrently`] runs them: node `i`
/// of the file read over `clients[i]`, each on its own thread.
pub fn verify_concurrently<T: Transport + Send>(
    clients: &mut [Client<T>],
    network: &Network,
) -> Result<Vec<Verdict>, ToolError> {
    side_by_side(clients, network, |client, spec| {
        verify_one(client, network, spec)
    })?
    .into_iter()
    .collect()
}

/// Runs `job` for node `i` of `network` with `clients[i]`, each on a thread of its own;
/// returns the results in file order. Fails when there are fewer clients than nodes.
fn side_by_side<T, R, F>(
    clients: &mut [Client<T>],
    network: &Network,
    job: F,
) -> Result<Vec<R>, ToolError>
where
    T: Transport + Send,
    R: Send,
    F: Fn(&mut Client<T>, &NodeSpec) -> R + Sync,
{
    if clients.len() < network.nodes.len() {
        return Err(ToolError::Usage(format!(
            "{} node(s) to work on side by side, but {} client(s) to do it with",
            network.nodes.len(),
            clients.len()
        )));
    }
    let job = &job;
    Ok(std::thread::scope(|scope| {
        let running: Vec<_> = clients
            .iter_mut()
            .zip(&network.nodes)
            .map(|(client, spec)| scope.spawn(move || job(client, spec)))
            .collect();
        running
            .into_iter()
            .map(|thread| {
                thread
                    .join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            })
            .collect()
    }))
}

/// One operator shared by the threads of [`configure_concurrently`]: each call holds it alone,
/// so the person is told or asked about one node at a time.
struct SharedOperator<'a, 'b>(&'a std::sync::Mutex<&'b mut (dyn Operator + Send)>);

impl SharedOperator<'_, '_> {
    fn with<R>(&mut self, call: impl FnOnce(&mut dyn Operator) -> R) -> R {
        // A thread that panicked while holding it cannot have left it half-told.
        let mut operator = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        call(&mut **operator)
    }
}

impl Operator for SharedOperator<'_, '_> {
    fn note(&mut self, line: &str) {
        self.with(|operator| operator.note(line));
    }
    fn confirm_identity(&mut self, node: &NodeSpec, differences: &str) -> bool {
        self.with(|operator| operator.confirm_identity(node, differences))
    }
    fn secret(&mut self, node: u8) -> Result<Option<Secret>, ToolError> {
        self.with(|operator| operator.secret(node))
    }
}

/// One node of [`configure`]: its SRDOs ([`configure_node`]) and, when the file has a
/// SimpleCAN section, its SimpleCAN objects. `Err` only for a transport failure; anything
/// else is the node's [`NodeResult::Failed`], told to the operator.
fn configure_one<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
    spec: &NodeSpec,
    operator: &mut dyn Operator,
) -> Result<NodeResult<Configured>, ToolError> {
    let configured = configure_node(client, spec, operator).and_then(|mut done| {
        if let Some(simplecan) = &network.simplecan {
            let before = client.requests;
            done.simplecan_signature =
                Some(configure_simplecan(client, simplecan, spec.id, operator)?);
            done.sdo_requests += client.requests - before;
        }
        Ok(done)
    });
    match configured {
        Ok(done) => Ok(NodeResult::Done(done)),
        Err(ToolError::Transport(error)) => Err(ToolError::Transport(error)),
        Err(error) => {
            operator.note(&error.to_string());
            Ok(NodeResult::Failed {
                node: spec.id,
                error: error.to_string(),
            })
        }
    }
}

/// The report of [`configure`] from each node's result; starts the nodes (NMT start, each
/// node, over `client`) only when `start` is set and every node was configured.
fn finish_configure<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
    lss: Option<crate::lss::FastscanReport>,
    nodes: Vec<NodeResult<Configured>>,
    start: bool,
) -> Result<ConfigureReport, ToolError> {
    let mut report = ConfigureReport {
        lss,
        nodes,
        started: false,
    };
    if start && report.success() {
        for spec in &network.nodes {
            client.nmt(NmtCommand::Start, spec.id)?;
        }
        report.started = true;
    }
    Ok(report)
}

/// Configures node `node`'s SimpleCAN objects from the file's SimpleCAN section, after
/// [`configure_node`] checked its identity (SC_REQ_37/38), unlocked it (SC_REQ_43) and put it
/// in Pre-operational (SC_REQ_39): the plan of [`crate::simplecan::plan`] (SC_REQ_35/36).
/// Returns the signature written to 0x5EFF; any difference leaves 0x5EFE at 0.
pub fn configure_simplecan<T: Transport>(
    client: &mut Client<T>,
    simplecan: &crate::simplecan::SimpleCanNetwork,
    node: u8,
    operator: &mut dyn Operator,
) -> Result<u32, ToolError> {
    let config = crate::simplecan::node_config(simplecan, node);
    operator.note(&format!(
        "node {node}: SimpleCAN {} with {} SDD entries: writing, reading back",
        if config.enabled == 1 { "on" } else { "off" },
        config.entries.len()
    ));
    let plan = crate::simplecan::plan::configure_plan(&config);
    match crate::simplecan::plan::execute(client, &config, &plan) {
        Ok(value) => {
            operator.note(&format!(
                "node {node}: SimpleCAN configured, signed ({value:08X}h), valid and stored"
            ));
            Ok(value)
        }
        Err(error) => {
            operator.note(&format!(
                "node {node}: 0x5EFE set to 0 (SimpleCAN configuration not valid)"
            ));
            Err(error)
        }
    }
}

/// What `verify` found on one node.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum Verdict {
    /// Everything the node holds equals the file, every signature is right, 0x13FE is A5h.
    Matches {
        /// The node-ID.
        node: u8,
    },
    /// The node holds something else than the file (or a wrong signature).
    Differs {
        /// The node-ID.
        node: u8,
        /// One line per difference (file vs node).
        diff: Vec<String>,
    },
    /// The node holds the file's configuration but has not declared it valid.
    NotValidated {
        /// The node-ID.
        node: u8,
        /// The value of 0x13FE.
        configuration_valid: u8,
    },
    /// The node holds the file's SimpleCAN configuration but has not declared it valid.
    SimpleCanNotValidated {
        /// The node-ID.
        node: u8,
        /// The value of 0x5EFE.
        configuration_valid: u8,
    },
    /// The node could not be read.
    Unreachable {
        /// The node-ID.
        node: u8,
        /// Why, as a sentence.
        error: String,
    },
}

/// Reads the whole safety configuration of one node and judges it against the file.
pub fn verify_node<T: Transport>(
    client: &mut Client<T>,
    spec: &NodeSpec,
) -> Result<Verdict, ToolError> {
    let node = spec.id;
    let mut diff = Vec::new();
    let identity = read_identity(client, node)?;
    let differences = identity_differences(&spec.identity, &identity);
    if !differences.is_empty() {
        diff.push(format!("identity (1018h): {differences}"));
    }
    let valid = client.read_unsigned(node, Address::new(0x13FE, 0), 1)? as u8;
    let count = srdo_count(client, node)?;
    for srdo in spec.srdos.iter().filter(|srdo| srdo.number > count) {
        diff.push(format!(
            "SRDO {}: in the file, but the node has {count}",
            srdo.number
        ));
    }
    for n in 1..=count {
        let held = read_record(client, node, n)?;
        let wanted = spec
            .srdos
            .iter()
            .find(|srdo| srdo.number == n)
            .map(|srdo| &srdo.settings);
        diff.extend(record_diff(n, wanted, &held));
        let expected = signature(&held.settings);
        let stored = client.read_unsigned(node, Address::new(0x13FF, n), 2)? as u16;
        if stored != expected {
            diff.push(format!(
                "signature of SRDO {n} (13FFh:{n:02X}h): computed from the node's values {expected:04X}h, node holds {stored:04X}h"
            ));
        }
    }
    Ok(if !diff.is_empty() {
        Verdict::Differs { node, diff }
    } else if valid != CONFIGURATION_VALID {
        Verdict::NotValidated {
            node,
            configuration_valid: valid,
        }
    } else {
        Verdict::Matches { node }
    })
}

/// Verifies every node of `network`; a node that does not answer is reported, not fatal.
pub fn verify<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
) -> Result<Vec<Verdict>, ToolError> {
    network
        .nodes
        .iter()
        .map(|spec| verify_one(client, network, spec))
        .collect()
}

/// One node of [`verify`]: its SRDOs ([`verify_node`]) and, when the file has a SimpleCAN
/// section, its SimpleCAN objects. `Err` only for a transport failure; a node that cannot be
/// read is [`Verdict::Unreachable`].
fn verify_one<T: Transport>(
    client: &mut Client<T>,
    network: &Network,
    spec: &NodeSpec,
) -> Result<Verdict, ToolError> {
    let verdict = verify_node(client, spec).and_then(|verdict| match &network.simplecan {
        Some(simplecan) => {
            let file = crate::simplecan::node_config(simplecan, spec.id);
            let checked = crate::simplecan::plan::verify(client, &file)?;
            Ok(with_simplecan(verdict, checked))
        }
        None => Ok(verdict),
    });
    match verdict {
        Err(ToolError::Transport(error)) => Err(ToolError::Transport(error)),
        Err(error) => Ok(Verdict::Unreachable {
            node: spec.id,
            error: error.to_string(),
        }),
        verdict => verdict,
    }
}

/// The verdict on a node's SRDOs joined with what was found on its SimpleCAN objects: any
/// difference makes it [`Verdict::Differs`]; a node valid for its SRDOs but not for
/// SimpleCAN is [`Verdict::SimpleCanNotValidated`].
fn with_simplecan(verdict: Verdict, checked: crate::simplecan::plan::Checked) -> Verdict {
    let crate::simplecan::plan::Checked {
        diff: simplecan_diff,
        configuration_valid,
    } = checked;
    match verdict {
        Verdict::Differs { node, mut diff } => {
            diff.extend(simplecan_diff);
            Verdict::Differs { node, diff }
        }
        Verdict::Matches { node } | Verdict::NotValidated { node, .. }
            if !simplecan_diff.is_empty() =>
        {
            Verdict::Differs {
                node,
                diff: simplecan_diff,
            }
        }
        Verdict::Matches { node } if configuration_valid != crate::simplecan::VALID => {
            Verdict::SimpleCanNotValidated {
                node,
                configuration_valid,
            }
        }
        other => other,
    }
}

/// A node found by `scan`.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Found {
    /// The node-ID.
    pub node: u8,
    /// The NMT state its last boot-up or heartbeat reported (CiA 301 7.2.8.3.2.1).
    pub state: &'static str,
    /// Its identity, or why it could not be read.
    pub identity: Result<NodeIdentity, String>,
}

/// The NMT state of a heartbeat byte, in words.
pub fn heartbeat_state(byte: u8) -> &'static str {
    match byte & 0x7F {
        0x00 => "boot-up",
        0x04 => "stopped",
        0x05 => "operational",
        0x7F => "pre-operational",
        _ => "unknown state",
    }
}

/// Listens for boot-up and heartbeat messages for `listen`, then reads each node's identity.
pub fn scan<T: Transport>(
    client: &mut Client<T>,
    listen: Duration,
) -> Result<Vec<Found>, ToolError> {
    let mut seen: std::collections::BTreeMap<u8, u8> = Default::default();
    for (_, frame) in client.listen(listen)? {
        let id = frame.id().raw();
        if (0x701..=0x77F).contains(&id) && frame.data().len() == 1 {
            seen.insert((id - 0x700) as u8, frame.data()[0]);
        }
    }
    let mut found = Vec::new();
    for (node, state) in seen {
        let identity = read_identity(client, node).map_err(|error| error.to_string());
        found.push(Found {
            node,
            state: heartbeat_state(state),
            identity,
        });
    }
    Ok(found)
}

/// The signatures of every SRDO in the file, computed offline: (node, SRDO, signature).
pub fn offline_signatures(network: &Network) -> Vec<(u8, u8, u16)> {
    network
        .nodes
        .iter()
        .flat_map(|node| {
            node.srdos
                .iter()
                .map(move |srdo| (node.id, srdo.number, signature(&srdo.settings)))
        })
        .collect()
}

/// Each node's SimpleCAN configuration and its signature (the tool's own CRC-32), computed
/// offline, in file order; empty when the file has no SimpleCAN section.
pub fn offline_simplecan(network: &Network) -> Vec<(crate::simplecan::NodeConfig, u32)> {
    let Some(simplecan) = &network.simplecan else {
        return Vec::new();
    };
    network
        .nodes
        .iter()
        .map(|node| {
            let config = crate::simplecan::node_config(simplecan, node.id);
            let value = crate::simplecan::signature::signature(&config);
            (config, value)
        })
        .collect()
}

/// `object`, for messages outside this module.
pub fn describe(address: Address) -> String {
    Object(address).to_string()
}

/// The object dictionary `node` serves, as its EDS lists it: the CANopen Safety device's
/// ([`crate::eds::objects`]), or, when it answers at 5E00h, the one of a device with
/// SimpleCAN ([`crate::eds::simplecan_objects`]) for its SRDOs (13FFh:00) and its SDD
/// entries (5E10h.. up to the first that is not there, 0602 0000h).
pub fn dictionary_of<T: Transport>(
    client: &mut Client<T>,
    node: u8,
) -> Result<Vec<crate::eds::Object>, ToolError> {
    use shared::canopen::od::AbortCode;
    use shared::canopen::sdo_client::ClientError;
    use shared::node::simplecan::{CYCLE_INDEX, FIRST_ENTRY_INDEX};
    use shared::simplecan::sdd::MAX_ENTRIES;
    let absent = |result: Result<Vec<u8>, ToolError>| match result {
        Ok(_) => Ok(false),
        Err(error)
            if error.sdo_client_error() == Some(ClientError::Aborted(AbortCode::NoObject)) =>
        {
            Ok(true)
        }
        Err(error) => Err(error),
    };
    if absent(client.read(node, Address::new(CYCLE_INDEX, 0)))? {
        return Ok(crate::eds::objects());
    }
    let srdos = srdo_count(client, node)?;
    let mut entries = 0u8;
    while usize::from(entries) < MAX_ENTRIES
        && !absent(client.read(
            node,
            Address::new(FIRST_ENTRY_INDEX + u16::from(entries), 0),
        ))?
    {
        entries += 1;
    }
    crate::eds::simplecan_objects(entries, srdos).ok_or_else(|| {
        ToolError::Usage(format!(
            "node {node} serves SimpleCAN beside {srdos} SRDO(s): no device of this project \
             has that dictionary (no SRDOs, or 2 or more)"
        ))
    })
}

/// Reads every entry of the object dictionary `node` serves ([`dictionary_of`]) and returns
/// its DCF (CiA 306): the EDS with `[DeviceComissioning]` and each value read as
/// `ParameterValue`, signatures and 0x13FE included (and SimpleCAN's objects, 5EFFh and
/// 5EFEh, on a node that has them). `name` names the node in it.
pub fn read_dcf<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    name: Option<&str>,
) -> Result<String, ToolError> {
    let objects = dictionary_of(client, node)?;
    let mut values = std::collections::BTreeMap::new();
    for object in &objects {
        // Write-only entries (the secret's, SC_REQ_43) have no value to read.
        for entry in object.entries.iter().filter(|entry| entry.access != "wo") {
            let bytes = client.read(node, entry.address)?;
            values.insert(entry.address, crate::eds::format_value(entry, &bytes));
        }
    }
    Ok(crate::eds::dcf(
        &objects,
        &crate::eds::Commissioning {
            node,
            name,
            values: &values,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn configured(signatures: Vec<(u8, u16)>, simplecan_signature: Option<u32>) -> Configured {
        Configured {
            node: 1,
            identity: NodeIdentity {
                vendor: 0xABC,
                product: 0x304,
                revision: 1,
                serial: 1,
            },
            signatures,
            simplecan_signature,
            sdo_requests: 0,
        }
    }

    /// Each SRDO's signature by number; a node that speaks SimpleCAN instead of SRDOs is said
    /// to have none, and its SimpleCAN signature follows.
    #[test]
    fn the_signatures_are_said_per_srdo_or_that_there_are_none() {
        let both = configured(vec![(1, 0x1A2B), (2, 0x0003)], Some(0x7B6D_1DE5));
        assert_eq!(
            both.signatures_in_words(),
            "SRDO 1 1A2Bh, SRDO 2 0003h; SimpleCAN 7B6D1DE5h (0x5EFF)"
        );
        let without_srdos = configured(Vec::new(), Some(0xEEEB_7FBE));
        assert_eq!(
            without_srdos.signatures_in_words(),
            "no SRDOs; SimpleCAN EEEB7FBEh (0x5EFF)"
        );
        assert_eq!(
            configured(vec![(4, 0xFFFF)], None).signatures_in_words(),
            "SRDO 4 FFFFh"
        );
    }
}
