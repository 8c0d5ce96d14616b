//! LSS master (CiA 305 Layer Setting Services) over a [`Transport`]: find unconfigured nodes
//! by fastscan and give each the node-ID the network file assigns to its identity; set a
//! node's node-ID or bit rate, store them, inquire them.
//!
//! The requests are the ones the node's slave answers (`shared::canopen::lss`, whose module
//! documentation has the table of services and the node's safety rules); the wire format
//! follows CANopenNode (`305/CO_LSSmaster.c`) and python-canopen (`canopen/lss.py`).
//!
//! # Finding every unconfigured node
//! Fastscan (CiA 305 Fig. 46) asks "does any unconfigured node's identity have these bits?":
//! every node whose bits match answers 4Fh, and the master hears one answer or none. The
//! plain scan (CANopenNode's, python-canopen's) guesses each of the 128 bits 0 and takes 1
//! when nobody answers, so it finds the *smallest* identity. A node the network file does not
//! know keeps no node-ID and would be found again by every later scan, hiding the nodes above
//! it; so this master looks for the smallest identity *above* the last one found
//! ([`LssMaster::fastscan_after`]): the successor of `X` shares the longest prefix with `X`
//! that is followed by a 1 where `X` has a 0, so it asks, from the lowest bit of `X`
//! upwards, whether a node with `X`'s prefix and that 1 exists, and scans the smallest
//! identity under the first that does. Every answer is waited for the whole timeout: several
//! nodes may answer one request, and a late answer taken for the next request's would
//! corrupt the scan (CANopenNode and lely-core wait the same way).
//!
//! # The nodes the file names first
//! The scan learns a node's 128 bits one request at a time, and every request nobody
//! answers costs the whole timeout: about half of them. Most nodes to be configured are
//! named in the network file by their whole identity (revision included), so
//! [`LssMaster::fastscan_assign`] first asks whether any unconfigured node is there (the
//! scan's reset, done at the first answer), then selects each such node by its identity
//! (switch state selective, Fig. 32: only that node answers), asks its active node-ID
//! (Fig. 41: only a node that answers FFh is given one; a configured node is switched back
//! and left alone) and configures it, each answer taken as it comes: every one of these
//! answers comes from the one node selected, or has a specifier of its own. It asks again
//! after each node; when nobody answers, no unconfigured node is left and it is done, the
//! one timeout of the whole run. Nodes the file names without a revision, and nodes it does
//! not name, are then found by the scan above. A named node that is absent (or in
//! Operational, where it answers no selection) costs one timeout.
//!
//! Every error names the node (its identity, or "the selected node") and the step.

use crate::network_file::{Network, NodeSpec};
use crate::procedure::{NodeIdentity, identity_differences};
use crate::transport::{Transport, TransportError};
use shared::CanFrame;
use shared::canopen::lss::{self, BitRate, specifier};
use std::time::Duration;

/// An identity as four numbers: vendor-ID, product code, revision, serial number.
pub fn parts(identity: NodeIdentity) -> [u32; 4] {
    [
        identity.vendor,
        identity.product,
        identity.revision,
        identity.serial,
    ]
}

/// The identity of four numbers (vendor-ID, product code, revision, serial number).
pub fn identity(parts: [u32; 4]) -> NodeIdentity {
    let [vendor, product, revision, serial] = parts;
    NodeIdentity {
        vendor,
        product,
        revision,
        serial,
    }
}

/// Parses an LSS address `VENDOR:PRODUCT:REVISION:SERIAL`, each decimal or `0x` hexadecimal.
pub fn parse_identity(text: &str) -> Result<NodeIdentity, LssError> {
    let bad = || {
        LssError::Usage(format!(
            "{text:?} is not an identity VENDOR:PRODUCT:REVISION:SERIAL (each a number, decimal or 0x-hexadecimal, as object 1018h holds them)"
        ))
    };
    let numbers: Vec<u32> = text
        .split(':')
        .map(|part| {
            let part = part.trim();
            match part.strip_prefix("0x").or_else(|| part.strip_prefix("0X")) {
                Some(hex) => u32::from_str_radix(hex, 16),
                None => part.parse(),
            }
        })
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    let parts: [u32; 4] = numbers.try_into().map_err(|_| bad())?;
    Ok(identity(parts))
}

/// Which node a step was for, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Target {
    /// The node with this identity.
    Node(NodeIdentity),
    /// The node (or nodes) switched to the LSS configuration state by switch state global.
    Selected,
    /// Every unconfigured node (fastscan before a node is found).
    Unconfigured,
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Target::Node(identity) => write!(f, "the node with {identity}"),
            Target::Selected => f.write_str("the node in LSS configuration state"),
            Target::Unconfigured => f.write_str("the unconfigured nodes"),
        }
    }
}

/// The meaning of an error code of configure node-ID, configure bit timing or store
/// configuration (CiA 305 Fig. 33, 34, 36), with the manufacturer-specific byte after FFh.
pub fn error_meaning(command: u8, code: u8, detail: u8) -> String {
    match (command, code) {
        (specifier::CONFIGURE_NODE_ID, lss::REFUSED) => {
            "the node-ID is out of range (1 to 127, or FFh for none)".into()
        }
        (specifier::CONFIGURE_NODE_ID, lss::MANUFACTURER_SPECIFIC)
            if detail == lss::SWITCHES_SET =>
        {
            "the node's node-ID switches are set, and they win over LSS: open them all to let LSS set the node-ID".into()
        }
        (specifier::CONFIGURE_BIT_TIMING, lss::REFUSED) => {
            "the bit rate is not in the CiA 301 table or the node does not support it".into()
        }
        (specifier::STORE_CONFIGURATION, lss::REFUSED) => {
            "the node cannot store its LSS settings".into()
        }
        (specifier::STORE_CONFIGURATION, lss::STORE_FAILED) => {
            "the node's storage medium failed (what it stored before is still in force)".into()
        }
        (_, lss::MANUFACTURER_SPECIFIC) => {
            format!("a manufacturer-specific error, {detail:02X}h")
        }
        _ => "an error code CiA 305 reserves".into(),
    }
}

/// What went wrong, naming the node and the step.
#[derive(Debug, thiserror::Error)]
pub enum LssError {
    /// No LSS answer came.
    #[error(
        "{target}: {step}: no LSS answer within {timeout_ms} ms (is the node on the bus, at this bit rate, in NMT Pre-operational or Stopped, and is its identity right?)"
    )]
    NoAnswer {
        /// The node.
        target: Target,
        /// The step.
        step: &'static str,
        /// The timeout.
        timeout_ms: u64,
    },
    /// The node answered with an error code.
    #[error("{target}: {step}: the node refused with error code {code:02X}h: {meaning}", meaning = error_meaning(*command, *code, *detail))]
    Refused {
        /// The node.
        target: Target,
        /// The step.
        step: &'static str,
        /// The request's command specifier.
        command: u8,
        /// The error code.
        code: u8,
        /// The manufacturer-specific error after FFh.
        detail: u8,
    },
    /// More than one node answered a request meant for one.
    #[error(
        "{target}: {step}: {count} nodes answered; LSS without an identity needs exactly one LSS node in the configuration state (name the node's identity)"
    )]
    Ambiguous {
        /// The node.
        target: Target,
        /// The step.
        step: &'static str,
        /// How many answered.
        count: usize,
    },
    /// Fastscan lost the node it was scanning (it left the bus or was configured meanwhile).
    #[error(
        "fastscan: {step}: no node answered for the identity found so far ({found}); did a node leave the bus or get a node-ID during the scan?"
    )]
    Lost {
        /// The step.
        step: &'static str,
        /// The identity scanned so far.
        found: NodeIdentity,
    },
    /// The node given a node-ID did not boot on it.
    #[error(
        "{target}: node-ID {node_id}: no boot-up message within {timeout_ms} ms of switching it back to LSS waiting (CiA 305: an unconfigured node takes its new node-ID then)"
    )]
    NoBootUp {
        /// The node.
        target: Target,
        /// The node-ID given.
        node_id: u8,
        /// The timeout.
        timeout_ms: u64,
    },
    /// A command-line value is not right.
    #[error("{0}")]
    Usage(String),
    /// The CAN interface failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
}

/// A node fastscan found and gave a node-ID.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Assigned {
    /// Its identity.
    pub identity: NodeIdentity,
    /// The node-ID the network file gives it.
    pub node_id: u8,
    /// Its name in the file.
    pub name: Option<String>,
    /// `true` when the node stored the node-ID (store configuration).
    pub stored: bool,
}

/// What [`LssMaster::fastscan_assign`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FastscanReport {
    /// The nodes given a node-ID, in identity order.
    pub assigned: Vec<Assigned>,
    /// Unconfigured nodes the file does not know (left unconfigured).
    pub unknown: Vec<NodeIdentity>,
    /// Unconfigured nodes whose file node-ID was given to another node found before (two
    /// nodes match one entry: its revision is not pinned); left unconfigured.
    pub duplicates: Vec<(NodeIdentity, u8)>,
    /// LSS requests sent.
    pub requests: u64,
    /// LSS answers received.
    pub answers: u64,
}

/// The LSS master's side of the bus.
pub struct LssMaster<T: Transport> {
    /// The interface.
    pub transport: T,
    /// How long a request waits for its answers.
    pub timeout: Duration,
    /// LSS requests sent.
    pub requests: u64,
    /// LSS answers received.
    pub answers: u64,
    /// The identity parts the fastscan has moved every matching node past since the last
    /// reset (bit check 80h): the slaves' scan position is their count. `None` when the
    /// positions are not known (before the first reset, and after a switch state global,
    /// which resets them in some slaves, lely-core's, and not in others, CANopenNode's).
    locked: Option<Vec<u32>>,
}

/// An 8-byte LSS answer in `frame`, if it is one.
fn lss_answer(frame: &CanFrame) -> Option<[u8; 8]> {
    if frame.id() != lss::SLAVE_TO_MASTER || frame.is_remote() {
        return None;
    }
    <[u8; 8]>::try_from(frame.data()).ok()
}

impl<T: Transport> LssMaster<T> {
    /// A master on `transport` whose requests wait `timeout` for their answers.
    pub fn new(transport: T, timeout: Duration) -> Self {
        LssMaster {
            transport,
            timeout,
            requests: 0,
            answers: 0,
            locked: None,
        }
    }

    fn timeout_ms(&self) -> u64 {
        u64::try_from(self.timeout.as_millis()).unwrap_or(u64::MAX)
    }

    /// Sends `data` after dropping what arrived before (it cannot answer this request).
    fn send(&mut self, data: [u8; 8]) -> Result<(), TransportError> {
        let now = self.transport.now();
        while self.transport.receive(now)?.is_some() {}
        self.requests += 1;
        let frame = CanFrame::new(lss::MASTER_TO_SLAVE, &data)
            .map_err(|_| TransportError::Protocol("an LSS request is 8 bytes".into()))?;
        self.transport.send(&frame)
    }

    /// Sends `data`, then gathers every LSS answer whose specifier is `expect` for the whole
    /// timeout.
    fn gather(&mut self, data: [u8; 8], expect: u8) -> Result<Vec<[u8; 8]>, TransportError> {
        self.send(data)?;
        let deadline = self.transport.now() + self.timeout;
        let mut found = Vec::new();
        while let Some(frame) = self.transport.receive(deadline)? {
            if let Some(answer) = lss_answer(&frame).filter(|answer| answer[0] == expect) {
                self.answers += 1;
                found.push(answer);
            }
        }
        Ok(found)
    }

    /// Sends `data` and returns the first LSS answer whose specifier is `expect`.
    fn confirmed(
        &mut self,
        data: [u8; 8],
        expect: u8,
        target: Target,
        step: &'static str,
    ) -> Result<[u8; 8], LssError> {
        self.send(data)?;
        let deadline = self.transport.now() + self.timeout;
        while let Some(frame) = self.transport.receive(deadline)? {
            if let Some(answer) = lss_answer(&frame).filter(|answer| answer[0] == expect) {
                self.answers += 1;
                return Ok(answer);
            }
        }
        Err(LssError::NoAnswer {
            target,
            step,
            timeout_ms: self.timeout_ms(),
        })
    }

    /// A configure service (Fig. 33, 34, 36): its error code must be 0.
    fn configure(
        &mut self,
        data: [u8; 8],
        target: Target,
        step: &'static str,
    ) -> Result<(), LssError> {
        let answer = self.confirmed(data, data[0], target, step)?;
        match answer {
            [_, lss::OK, ..] => Ok(()),
            [command, code, detail, ..] => Err(LssError::Refused {
                target,
                step,
                command,
                code,
                detail,
            }),
        }
    }

    /// Switch state global (Fig. 31): every node to the configuration state (`true`) or back
    /// to waiting. Not answered.
    pub fn switch_global(&mut self, configuration: bool) -> Result<(), LssError> {
        let mode = u8::from(configuration);
        self.locked = None;
        self.send([specifier::SWITCH_GLOBAL, mode, 0, 0, 0, 0, 0, 0])?;
        Ok(())
    }

    /// Switch state selective (Fig. 32): the node with `identity` to the configuration state.
    pub fn select(&mut self, identity: NodeIdentity) -> Result<(), LssError> {
        let parts = parts(identity);
        for (part, &value) in parts.iter().enumerate().take(3) {
            let [a, b, c, d] = value.to_le_bytes();
            let command = specifier::SWITCH_SELECTIVE_VENDOR + part as u8;
            self.send([command, a, b, c, d, 0, 0, 0])?;
        }
        let [a, b, c, d] = parts[3].to_le_bytes();
        self.confirmed(
            [specifier::SWITCH_SELECTIVE_SERIAL, a, b, c, d, 0, 0, 0],
            specifier::SWITCH_SELECTIVE_ANSWER,
            Target::Node(identity),
            "switch state selective",
        )?;
        Ok(())
    }

    /// [`LssMaster::select`], `false` when no node answered (none with `identity` is in the
    /// LSS waiting state outside Operational).
    fn try_select(&mut self, identity: NodeIdentity) -> Result<bool, LssError> {
        match self.select(identity) {
            Ok(()) => Ok(true),
            Err(LssError::NoAnswer { .. }) => Ok(false),
            Err(error) => Err(error),
        }
    }

    /// Whether any unconfigured node is on the bus: the scan's reset (bit check 80h), done at
    /// the first answer. The other nodes' answers (the same 4Fh) may come after it; the next
    /// requests wait for other specifiers ([`LssMaster::fastscan_assign`]), and a scan
    /// request drops what arrived before it and waits its whole timeout.
    fn any_unconfigured(&mut self) -> Result<bool, LssError> {
        self.locked = Some(Vec::new());
        let data = [specifier::FASTSCAN, 0, 0, 0, 0, lss::FASTSCAN_CONFIRM, 0, 0];
        match self.confirmed(
            data,
            specifier::IDENTIFY_SLAVE,
            Target::Unconfigured,
            "fastscan",
        ) {
            Ok(_) => Ok(true),
            Err(LssError::NoAnswer { .. }) => Ok(false),
            Err(error) => Err(error),
        }
    }

    /// Configure node-ID (Fig. 33) of the node in the configuration state: `None` makes it
    /// unconfigured (FFh). Pending until its NMT reset communication, unless it was
    /// unconfigured.
    pub fn configure_node_id(
        &mut self,
        target: Target,
        node_id: Option<u8>,
    ) -> Result<(), LssError> {
        let raw = node_id.unwrap_or(lss::UNCONFIGURED);
        if !(1..=127).contains(&raw) && raw != lss::UNCONFIGURED {
            return Err(LssError::Usage(format!(
                "node-ID {raw} is not 1 to 127 (CiA 301)"
            )));
        }
        self.configure(
            [specifier::CONFIGURE_NODE_ID, raw, 0, 0, 0, 0, 0, 0],
            target,
            "configure node-ID",
        )
    }

    /// Configure bit timing (Fig. 34, table 0 of CiA 301) of the node in the configuration
    /// state.
    pub fn configure_bit_rate(&mut self, target: Target, rate: BitRate) -> Result<(), LssError> {
        self.configure(
            [
                specifier::CONFIGURE_BIT_TIMING,
                0,
                rate.index(),
                0,
                0,
                0,
                0,
                0,
            ],
            target,
            "configure bit timing",
        )
    }

    /// Activate bit timing (Fig. 35): every node in the configuration state switches to its
    /// pending bit rate after `delay_ms`, silent for `delay_ms` before and after. Not
    /// answered; this interface must be switched to the new bit rate by its owner.
    pub fn activate_bit_rate(&mut self, delay_ms: u16) -> Result<(), LssError> {
        let [low, high] = delay_ms.to_le_bytes();
        self.send([specifier::ACTIVATE_BIT_TIMING, low, high, 0, 0, 0, 0, 0])?;
        Ok(())
    }

    /// Store configuration (Fig. 36) of the node in the configuration state.
    pub fn store(&mut self, target: Target) -> Result<(), LssError> {
        self.configure(
            [specifier::STORE_CONFIGURATION, 0, 0, 0, 0, 0, 0, 0],
            target,
            "store configuration",
        )
    }

    /// Inquire the identity (Fig. 37 to 40) of the one node in the configuration state.
    pub fn inquire_identity(&mut self, target: Target) -> Result<NodeIdentity, LssError> {
        const STEPS: [&str; 4] = [
            "inquire vendor-ID",
            "inquire product code",
            "inquire revision number",
            "inquire serial number",
        ];
        let mut found = [0u32; 4];
        for (part, step) in STEPS.into_iter().enumerate() {
            let command = specifier::INQUIRE_VENDOR + part as u8;
            let [_, a, b, c, d, ..] = self.one(command, target, step)?;
            found[part] = u32::from_le_bytes([a, b, c, d]);
        }
        Ok(identity(found))
    }

    /// Inquire node-ID (Fig. 41) of the one node in the configuration state: its active
    /// node-ID, `None` when unconfigured.
    pub fn inquire_node_id(&mut self, target: Target) -> Result<Option<u8>, LssError> {
        let [_, raw, ..] = self.one(specifier::INQUIRE_NODE_ID, target, "inquire node-ID")?;
        Ok((raw != lss::UNCONFIGURED).then_some(raw))
    }

    /// An inquiry answered by exactly one node.
    fn one(
        &mut self,
        command: u8,
        target: Target,
        step: &'static str,
    ) -> Result<[u8; 8], LssError> {
        let answers = self.gather([command, 0, 0, 0, 0, 0, 0, 0], command)?;
        match answers.as_slice() {
            [answer] => Ok(*answer),
            [] => Err(LssError::NoAnswer {
                target,
                step,
                timeout_ms: self.timeout_ms(),
            }),
            more => Err(LssError::Ambiguous {
                target,
                step,
                count: more.len(),
            }),
        }
    }

    /// One fastscan request (Fig. 46): `true` when any node answered.
    fn scan(&mut self, value: u32, bit_check: u8, sub: u8, next: u8) -> Result<bool, LssError> {
        let [a, b, c, d] = value.to_le_bytes();
        let data = [specifier::FASTSCAN, a, b, c, d, bit_check, sub, next];
        Ok(!self.gather(data, specifier::IDENTIFY_SLAVE)?.is_empty())
    }

    /// Resets every unconfigured node's scan (bit check 80h): `true` when any is there.
    fn reset_scan(&mut self) -> Result<bool, LssError> {
        self.locked = Some(Vec::new());
        self.scan(0, lss::FASTSCAN_CONFIRM, 0, 0)
    }

    /// Whether an unconfigured node's identity starts with the first `len` bits (1 to 128)
    /// of `parts`, the vendor-ID's most significant bit first.
    ///
    /// The nodes' scan positions are reused where that is sound: the nodes at position
    /// `whole` (the part the question is about) are the ones that matched the parts locked
    /// before it; when a value was locked at `whole` already, the nodes it moved on are
    /// left out, which is right only when that value differs from `parts[whole]` in the bits
    /// asked. Otherwise the scan is reset and the parts before `whole` locked again.
    fn exists(&mut self, parts: &[u32; 4], len: usize) -> Result<bool, LssError> {
        let whole = ((len.max(1) - 1) / 32).min(3);
        let bit_check = (32 * (whole + 1) - len.min(32 * (whole + 1))) as u8;
        let mask = u32::MAX << bit_check;
        let reusable = self.locked.as_ref().is_some_and(|locked| {
            let kept = locked.len().min(whole);
            locked[..kept] == parts[..kept]
                && (locked.len() <= whole || (locked[whole] ^ parts[whole]) & mask != 0)
        });
        if !reusable && !self.reset_scan()? {
            return Ok(false);
        }
        if !self.lock_up_to(parts, whole)? {
            return Ok(false);
        }
        self.scan(parts[whole], bit_check, whole as u8, whole as u8)
    }

    /// Moves the nodes matching `parts[..whole]` to scan position `whole` (the parts locked
    /// so far are a prefix of `parts`): `false` when none matched.
    fn lock_up_to(&mut self, parts: &[u32; 4], whole: usize) -> Result<bool, LssError> {
        loop {
            let sub = self.locked.as_ref().map_or(0, Vec::len);
            if sub >= whole {
                return Ok(true);
            }
            if !self.scan(parts[sub], 0, sub as u8, sub as u8 + 1)? {
                return Ok(false);
            }
            if let Some(locked) = self.locked.as_mut() {
                locked.push(parts[sub]);
            }
        }
    }

    /// The smallest identity of an unconfigured node that starts with the first `len` bits
    /// of `parts` (one exists), selected: it is in the configuration state on return.
    fn smallest_from(&mut self, mut parts: [u32; 4], len: usize) -> Result<NodeIdentity, LssError> {
        for position in len..128 {
            let whole = position / 32;
            let bit = 31 - position % 32;
            // The bits after the prefix are 0 so far; with this one 0 too, is anyone there?
            if !self.exists(&parts, position + 1)? {
                parts[whole] |= 1 << bit;
            }
        }
        // Lock the first three parts afresh when other values were locked, then select.
        let stale = self
            .locked
            .as_ref()
            .is_none_or(|locked| locked.len() > 3 || locked[..] != parts[..locked.len()]);
        if stale && !self.reset_scan()? {
            return Err(LssError::Lost {
                step: "select the node found",
                found: identity(parts),
            });
        }
        if !self.lock_up_to(&parts, 3)? || !self.scan(parts[3], 0, 3, 0)? {
            return Err(LssError::Lost {
                step: "select the node found",
                found: identity(parts),
            });
        }
        // The selected node went back to scan position 0, the others stay where they were.
        Ok(identity(parts))
    }

    /// Fastscan: the unconfigured node with the smallest identity above `after` (any when
    /// `None`), selected into the LSS configuration state; `None` when there is none.
    pub fn fastscan_after(
        &mut self,
        after: Option<NodeIdentity>,
    ) -> Result<Option<NodeIdentity>, LssError> {
        let Some(after) = after else {
            if !self.reset_scan()? {
                return Ok(None);
            }
            return self.smallest_from([0; 4], 0).map(Some);
        };
        // Most often every node found was given a node-ID: one request says none is left.
        if !self.reset_scan()? {
            return Ok(None);
        }
        let last = parts(after);
        for len in (1..=128usize).rev() {
            let whole = (len - 1) / 32;
            let bit = 31 - (len - 1) % 32;
            if last[whole] & (1 << bit) != 0 {
                continue;
            }
            // `after`'s first len − 1 bits, then a 1 where `after` has its 0.
            let mut candidate = [0u32; 4];
            candidate[..whole].copy_from_slice(&last[..whole]);
            let keep = if bit == 31 { 0 } else { u32::MAX << (bit + 1) };
            candidate[whole] = (last[whole] & keep) | (1 << bit);
            if self.exists(&candidate, len)? {
                return self.smallest_from(candidate, len).map(Some);
            }
        }
        Ok(None)
    }

    /// Waits the timeout for the boot-up message of `node_id` (CiA 301 7.2.8.3.2.1).
    fn boot_up(&mut self, target: Target, node_id: u8) -> Result<(), LssError> {
        let deadline = self.transport.now() + self.timeout;
        while let Some(frame) = self.transport.receive(deadline)? {
            if frame.id().raw() == 0x700 + u16::from(node_id) && frame.data() == [0] {
                return Ok(());
            }
        }
        Err(LssError::NoBootUp {
            target,
            node_id,
            timeout_ms: self.timeout_ms(),
        })
    }

    /// Finds every unconfigured node by fastscan and gives each the node-ID `network` assigns
    /// to its identity (stored when `store`), after which it boots on it; nodes the file does
    /// not know stay unconfigured and are reported.
    pub fn fastscan_assign(
        &mut self,
        network: &Network,
        store: bool,
    ) -> Result<FastscanReport, LssError> {
        let mut report = FastscanReport::default();
        let mut named: Vec<(NodeIdentity, &NodeSpec)> = network
            .nodes
            .iter()
            .filter_map(|spec| whole_identity(spec).map(|identity| (identity, spec)))
            .collect();
        named.sort_by_key(|(identity, _)| parts(*identity));
        let mut named = named.into_iter();
        let mut left = self.any_unconfigured()?;
        while left {
            let Some((identity, spec)) = named.next() else {
                break;
            };
            if !self.try_select(identity)? {
                continue;
            }
            let target = Target::Node(identity);
            let active = self.confirmed(
                [specifier::INQUIRE_NODE_ID, 0, 0, 0, 0, 0, 0, 0],
                specifier::INQUIRE_NODE_ID,
                target,
                "inquire node-ID",
            )?;
            if active[1] != lss::UNCONFIGURED {
                // Configured already: left as it is.
                self.switch_global(false)?;
                continue;
            }
            self.assign(target, spec, store, &mut report)?;
            left = self.any_unconfigured()?;
        }
        if left {
            self.scan_and_assign(network, store, &mut report)?;
        }
        report.requests = self.requests;
        report.answers = self.answers;
        Ok(report)
    }

    /// Gives the node `target` in the configuration state `spec`'s node-ID (stored when
    /// `store`), switches it back to waiting and waits for its boot-up.
    fn assign(
        &mut self,
        target: Target,
        spec: &NodeSpec,
        store: bool,
        report: &mut FastscanReport,
    ) -> Result<(), LssError> {
        self.configure_node_id(target, Some(spec.id))?;
        if store {
            self.store(target)?;
        }
        // CiA 305: back in the waiting state, the unconfigured node takes its node-ID by an
        // NMT reset communication of its own, and boots.
        self.switch_global(false)?;
        self.boot_up(target, spec.id)?;
        if let Target::Node(identity) = target {
            report.assigned.push(Assigned {
                identity,
                node_id: spec.id,
                name: spec.name.clone(),
                stored: store,
            });
        }
        Ok(())
    }

    /// The scan of [`LssMaster::fastscan_after`] over every unconfigured node left, each
    /// given the node-ID `network` assigns to its identity.
    fn scan_and_assign(
        &mut self,
        network: &Network,
        store: bool,
        report: &mut FastscanReport,
    ) -> Result<(), LssError> {
        let mut after = None;
        while let Some(found) = self.fastscan_after(after)? {
            after = Some(found);
            let target = Target::Node(found);
            let spec: Option<&NodeSpec> = network
                .nodes
                .iter()
                .find(|node| identity_differences(&node.identity, &found).is_empty());
            let Some(spec) = spec else {
                report.unknown.push(found);
                self.switch_global(false)?;
                continue;
            };
            if report.assigned.iter().any(|done| done.node_id == spec.id) {
                report.duplicates.push((found, spec.id));
                self.switch_global(false)?;
                continue;
            }
            self.assign(target, spec, store, report)?;
        }
        Ok(())
    }
}

/// The identity the file gives `spec` when it names every part of it (the revision pinned).
fn whole_identity(spec: &NodeSpec) -> Option<NodeIdentity> {
    let identity = &spec.identity;
    Some(NodeIdentity {
        vendor: identity.vendor,
        product: identity.product,
        revision: identity.revision?,
        serial: identity.serial,
    })
}

/// The `lss` subcommand's actions.
#[derive(Clone, Debug, PartialEq, Eq, clap::Subcommand)]
pub enum LssCommand {
    /// Find every unconfigured node (node-ID FFh) by fastscan and give each the node-ID the
    /// network file assigns to its identity; it boots on it at once. Nodes the file does not
    /// know stay unconfigured and are listed (the command then fails).
    Fastscan {
        /// The network file (TOML).
        file: String,
        /// Have each node store its node-ID (LSS store configuration), so it keeps it after a
        /// power cycle.
        #[arg(long)]
        store: bool,
    },
    /// Give the node with IDENTITY a node-ID (1 to 127, or `none` to make it unconfigured).
    /// It takes effect at the node's next NMT reset communication (at once for an
    /// unconfigured node); the node's safety configuration must then be validated again for
    /// the new node-ID.
    SetId {
        /// The node's identity, VENDOR:PRODUCT:REVISION:SERIAL (object 1018h).
        identity: String,
        /// The node-ID, or `none`.
        node_id: String,
        /// Store it (LSS store configuration).
        #[arg(long)]
        store: bool,
    },
    /// Set the bit rate (bit/s, of the CiA 301 table) the node with IDENTITY switches to at
    /// the next activate-bitrate, or starts on after storing it.
    SetBitrate {
        /// The node's identity, VENDOR:PRODUCT:REVISION:SERIAL (object 1018h).
        identity: String,
        /// The bit rate in bit/s (1000000, 800000, 500000, 250000, 125000, 50000, 20000,
        /// 10000).
        bit_rate: u32,
        /// Store it (LSS store configuration).
        #[arg(long)]
        store: bool,
    },
    /// Switch every node to the LSS configuration state and have them all switch to their
    /// configured bit rate after DELAY_MS, silent for DELAY_MS before and after (CiA 305
    /// Fig. 35). Switch this interface to the new bit rate meanwhile; the nodes stay in the
    /// configuration state until a master switches them back at the new rate.
    ActivateBitrate {
        /// The switch delay in milliseconds.
        delay_ms: u16,
    },
    /// Have the node with IDENTITY store its LSS settings (node-ID and bit rate).
    Store {
        /// The node's identity, VENDOR:PRODUCT:REVISION:SERIAL (object 1018h).
        identity: String,
    },
    /// Read the identity and the active node-ID of the node with IDENTITY, or of the only
    /// LSS node on the bus when none is given.
    Inquire {
        /// The node's identity, VENDOR:PRODUCT:REVISION:SERIAL (object 1018h).
        identity: Option<String>,
    },
}

/// What an `lss` action did: a text for a person, the same as JSON, and whether it did all it
/// was asked.
#[derive(Clone, Debug, PartialEq)]
pub struct LssOutput {
    /// Lines for a person.
    pub text: String,
    /// The same for scripts (`--json`).
    pub json: serde_json::Value,
    /// `false` when something was left undone (nodes the file does not know).
    pub complete: bool,
}

impl LssOutput {
    fn done(text: String, json: serde_json::Value) -> Self {
        LssOutput {
            text,
            json,
            complete: true,
        }
    }
}

/// The node-ID of the command line: 1 to 127, or `none` (unconfigured).
fn parse_node_id(text: &str) -> Result<Option<u8>, LssError> {
    if text.eq_ignore_ascii_case("none") {
        return Ok(None);
    }
    text.parse::<u8>()
        .ok()
        .filter(|id| (1..=127).contains(id))
        .map(Some)
        .ok_or_else(|| LssError::Usage(format!("{text:?} is not a node-ID 1 to 127, nor `none`")))
}

/// Runs `command` over `transport` with answers waited for `timeout`; `network` is the parsed
/// file of [`LssCommand::Fastscan`].
pub fn run<T: Transport>(
    transport: T,
    command: &LssCommand,
    network: Option<&Network>,
    timeout: Duration,
) -> Result<LssOutput, LssError> {
    let mut master = LssMaster::new(transport, timeout);
    let selected = |master: &mut LssMaster<T>, text: &str| -> Result<Target, LssError> {
        let identity = parse_identity(text)?;
        master.select(identity)?;
        Ok(Target::Node(identity))
    };
    match command {
        LssCommand::Fastscan { store, .. } => {
            let network =
                network.ok_or_else(|| LssError::Usage("fastscan needs the network file".into()))?;
            let report = master.fastscan_assign(network, *store)?;
            let mut text = String::new();
            for node in &report.assigned {
                let name = node
                    .name
                    .as_deref()
                    .map(|n| format!(" ({n})"))
                    .unwrap_or_default();
                let stored = if node.stored { ", stored" } else { "" };
                text.push_str(&format!(
                    "node {}{name}: {} given node-ID {}{stored}; it booted on it\n",
                    node.node_id, node.identity, node.node_id
                ));
            }
            for identity in &report.unknown {
                text.push_str(&format!(
                    "not in the network file, left unconfigured: {identity}\n"
                ));
            }
            for (identity, node_id) in &report.duplicates {
                text.push_str(&format!(
                    "matches node {node_id} of the file, whose node-ID another node took: {identity}; left unconfigured (pin the revision in the file)\n"
                ));
            }
            if report.assigned.is_empty() && report.unknown.is_empty() {
                text.push_str("no unconfigured node answered fastscan\n");
            }
            text.push_str(&format!(
                "{} LSS requests, {} answers\n",
                report.requests, report.answers
            ));
            let complete = report.unknown.is_empty() && report.duplicates.is_empty();
            let json = serde_json::to_value(&report).unwrap_or(serde_json::Value::Null);
            Ok(LssOutput {
                text,
                json,
                complete,
            })
        }
        LssCommand::SetId {
            identity,
            node_id,
            store,
        } => {
            let node_id = parse_node_id(node_id)?;
            let target = selected(&mut master, identity)?;
            master.configure_node_id(target, node_id)?;
            if *store {
                master.store(target)?;
            }
            master.switch_global(false)?;
            let shown = node_id.map_or("none (unconfigured)".to_owned(), |id| id.to_string());
            Ok(LssOutput::done(
                format!(
                    "{target}: node-ID {shown} pending{}; in force at the node's next NMT reset communication (at once if it was unconfigured)\n",
                    if *store { ", stored" } else { "" }
                ),
                serde_json::json!({"node_id": node_id, "stored": store}),
            ))
        }
        LssCommand::SetBitrate {
            identity,
            bit_rate,
            store,
        } => {
            let rate = BitRate::from_bits_per_second(*bit_rate).ok_or_else(|| {
                LssError::Usage(format!(
                    "{bit_rate} bit/s is not in the CiA 301 bit-timing table (1000000, 800000, 500000, 250000, 125000, 50000, 20000, 10000)"
                ))
            })?;
            let target = selected(&mut master, identity)?;
            master.configure_bit_rate(target, rate)?;
            if *store {
                master.store(target)?;
            }
            master.switch_global(false)?;
            Ok(LssOutput::done(
                format!(
                    "{target}: bit rate {bit_rate} bit/s pending{}; in force after activate-bitrate{}\n",
                    if *store { ", stored" } else { "" },
                    if *store { " or a power cycle" } else { "" }
                ),
                serde_json::json!({"bit_rate": bit_rate, "stored": store}),
            ))
        }
        LssCommand::ActivateBitrate { delay_ms } => {
            master.switch_global(true)?;
            master.activate_bit_rate(*delay_ms)?;
            Ok(LssOutput::done(
                format!(
                    "activate bit timing sent: the nodes in LSS configuration switch after {delay_ms} ms and stay silent {delay_ms} ms more; switch this interface to the new bit rate\n"
                ),
                serde_json::json!({"delay_ms": delay_ms}),
            ))
        }
        LssCommand::Store { identity } => {
            let target = selected(&mut master, identity)?;
            master.store(target)?;
            master.switch_global(false)?;
            Ok(LssOutput::done(
                format!("{target}: LSS settings stored\n"),
                serde_json::json!({"stored": true}),
            ))
        }
        LssCommand::Inquire { identity } => {
            let target = match identity {
                Some(text) => selected(&mut master, text)?,
                None => {
                    master.switch_global(true)?;
                    Target::Selected
                }
            };
            let result = master
                .inquire_identity(target)
                .and_then(|found| Ok((found, master.inquire_node_id(target)?)));
            // Back to waiting whatever happened: no node stays in the configuration state.
            master.switch_global(false)?;
            let (found, node_id) = result?;
            let shown = node_id.map_or("none (unconfigured)".to_owned(), |id| id.to_string());
            Ok(LssOutput::done(
                format!("{found}: active node-ID {shown}\n"),
                serde_json::json!({"identity": found, "node_id": node_id}),
            ))
        }
    }
}

#[cfg(test)]
mod tests;
