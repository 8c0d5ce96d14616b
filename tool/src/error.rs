//! Every error of the tool, as a sentence that names the node and the object (Display is the
//! message a person reads; `Debug` is never shown).

use crate::transport::TransportError;
use shared::canopen::od::{AbortCode, Address};

/// An object named for a person: `0x1301:05 (SRDO 1 COB-ID 1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Object(pub Address);

impl std::fmt::Display for Object {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Address { index, sub } = self.0;
        write!(f, "object {index:04X}h:{sub:02X}h")?;
        if let Some(name) = object_name(self.0) {
            write!(f, " ({name})")?;
        }
        Ok(())
    }
}

/// What the object is, for the objects this tool reads and writes.
pub fn object_name(address: Address) -> Option<String> {
    let Address { index, sub } = address;
    let comm = |n: u16| -> Option<String> {
        let field = match sub {
            0 => "highest sub-index",
            1 => "information direction",
            2 => "refresh time / SCT",
            3 => "SRVT",
            4 => "transmission type",
            5 => "COB-ID 1",
            6 => "COB-ID 2",
            _ => return None,
        };
        Some(format!("SRDO {n} {field}"))
    };
    match index {
        0x1010 => Some("store parameters".into()),
        0x1018 => Some(
            match sub {
                1 => "identity: vendor-ID",
                2 => "identity: product code",
                3 => "identity: revision",
                4 => "identity: serial number",
                _ => "identity",
            }
            .into(),
        ),
        0x1300 => Some("GFC parameter".into()),
        0x1301..=0x1340 => comm(index - 0x1300),
        0x1381..=0x13C0 if sub == 0 => Some(format!("SRDO {} mapping count", index - 0x1380)),
        0x1381..=0x13C0 => Some(format!("SRDO {} mapping entry {sub}", index - 0x1380)),
        0x13FE => Some("configuration valid".into()),
        0x13FF => Some(format!("signature of SRDO {sub}")),
        0x5E00..=0x5EFF => crate::simplecan::object_name(address),
        0x5C10 => Some(
            match sub {
                1 => "unlock",
                2 => "set secret",
                3 => "access state",
                4 => "failed unlock attempts",
                5 => "remaining unlock or lockout time",
                _ => "configuration access",
            }
            .into(),
        ),
        0x5C11 => Some("validated configuration changes".into()),
        0x5C12 => Some(format!(
            "signature of SRDO {sub} before the last validated change"
        )),
        0x5C13 => Some(format!(
            "signature of SRDO {sub} after the last validated change"
        )),
        _ => safety_device::OBJECT_NAMES
            .iter()
            .find(|(_, object)| *object == address)
            .map(|(name, _)| (*name).to_owned()),
    }
}

/// The CiA 301 meaning of an abort code, also for codes the node's crate does not know.
pub fn abort_meaning(code: u32) -> &'static str {
    AbortCode::from_code(code).map_or("an abort code this tool does not know", AbortCode::meaning)
}

impl ToolError {
    /// The error of shared's SDO client (`shared::canopen::sdo_client`) this one reports, for
    /// an error of one SDO transfer ([`crate::client::Client::read`] or `write`); `None` for
    /// every other error.
    pub fn sdo_client_error(&self) -> Option<shared::canopen::sdo_client::ClientError> {
        use shared::canopen::sdo_client::ClientError;
        match *self {
            ToolError::Aborted { code, .. } => Some(
                AbortCode::from_code(code)
                    .map_or(ClientError::UnknownAbort(code), ClientError::Aborted),
            ),
            ToolError::Timeout { .. } => Some(ClientError::NoResponse),
            ToolError::Protocol { .. } => Some(ClientError::Protocol),
            ToolError::TooLong { .. } => Some(ClientError::TooLong),
            _ => None,
        }
    }
}

/// What went wrong.
#[derive(Debug, thiserror::Error)]
pub enum ToolError {
    /// The node refused an SDO transfer.
    #[error("node {node}: {object}: the node aborted the SDO {action} with {code:08X}h: {meaning}", meaning = abort_meaning(*code))]
    Aborted {
        /// The node-ID.
        node: u8,
        /// The object.
        object: Object,
        /// `read` or `write`.
        action: &'static str,
        /// The abort code.
        code: u32,
    },
    /// The node did not answer in time.
    #[error(
        "node {node} did not answer within {timeout_ms} ms (SDO {action} of {object}); is it on the bus, powered, at this node-ID and bit rate?"
    )]
    Timeout {
        /// The node-ID.
        node: u8,
        /// The object.
        object: Object,
        /// `read` or `write`.
        action: &'static str,
        /// The SDO timeout in milliseconds.
        timeout_ms: u64,
    },
    /// The node's answer did not follow the SDO protocol.
    #[error(
        "node {node}: {object}: the answer to the SDO {action} does not follow the SDO protocol (CiA 301 7.2.4)"
    )]
    Protocol {
        /// The node-ID.
        node: u8,
        /// The object.
        object: Object,
        /// `read` or `write`.
        action: &'static str,
    },
    /// A value is longer than an SDO transfer of this tool carries.
    #[error("node {node}: {object}: the value is longer than {max} bytes")]
    TooLong {
        /// The node-ID.
        node: u8,
        /// The object.
        object: Object,
        /// The limit.
        max: usize,
    },
    /// A value read back has a length other than its object's data type.
    #[error(
        "node {node}: {object}: the node answered {got} bytes where the data type has {expected}"
    )]
    Length {
        /// The node-ID.
        node: u8,
        /// The object.
        object: Object,
        /// Bytes expected.
        expected: usize,
        /// Bytes received.
        got: usize,
    },
    /// The CAN interface failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The node's identity is not the one the network file expects (SC_REQ_37/38).
    #[error(
        "node {node} is not the device the network file expects: {differences}; nothing was written (pass --accept-identity to configure it anyway)"
    )]
    IdentityMismatch {
        /// The node-ID.
        node: u8,
        /// The fields that differ, as `serial number: file 2, node 7`.
        differences: String,
    },
    /// What the node holds after configuration is not what the file says.
    #[error(
        "node {node}: read-back differs from the network file, configuration left invalid (0x13FE not A5h):\n{diff}"
    )]
    ReadBackMismatch {
        /// The node-ID.
        node: u8,
        /// One line per difference.
        diff: String,
    },
    /// The node did not keep the validity declaration.
    #[error(
        "node {node}: 0x13FE reads {value:02X}h after {when}, not A5h: the node does not hold a valid configuration"
    )]
    NotValid {
        /// The node-ID.
        node: u8,
        /// The value read.
        value: u8,
        /// After which step.
        when: &'static str,
    },
    /// The node did not keep the validity declaration of its SimpleCAN configuration.
    #[error(
        "node {node}: 0x5EFE reads {value:02X}h after {when}, not A5h: the node does not hold a valid SimpleCAN configuration (docs/simplecan.md section 11)"
    )]
    SimpleCanNotValid {
        /// The node-ID.
        node: u8,
        /// The value read.
        value: u8,
        /// After which step.
        when: &'static str,
    },
    /// The node refused to store its parameters for its present state (0800 0022h on
    /// 0x1010:01): it stores outside Operational only, and into a flash slot erased while it
    /// started up, so a store after another store may have to wait for a power cycle
    /// (docs/parameter-storage.md).
    #[error(
        "node {node} refused to store its parameters (0x1010:01, abort 08000022h): a node stores only outside Operational, and only into flash it erased when it started, which an earlier store since then may have used; what the node holds is in force until it resets but not stored: power-cycle the node, configure it again and store"
    )]
    StoreRefused {
        /// The node-ID.
        node: u8,
    },
    /// The node refuses changes of its safety configuration until it is unlocked (SC_REQ_43).
    #[error(
        "node {node} is locked against changes of its safety configuration (SC_REQ_43); nothing was written (pass --unlock and give the node's secret)"
    )]
    Locked {
        /// The node-ID.
        node: u8,
    },
    /// The node refused the secret (0800 0020h) and counted a failed attempt.
    #[error(
        "node {node} refused the secret: a failed attempt, counted; the next attempt is possible in {lockout_ms} ms"
    )]
    WrongSecret {
        /// The node-ID.
        node: u8,
        /// The lockout that the failure started, ms.
        lockout_ms: u32,
    },
    /// The node refused an unlock attempt without looking at it (0800 0022h): too many
    /// failed attempts.
    #[error(
        "node {node} is locked out after too many failed attempts; it takes the next attempt in {remaining_ms} ms"
    )]
    LockedOut {
        /// The node-ID.
        node: u8,
        /// What is left of the lockout, ms.
        remaining_ms: u32,
    },
    /// The network file could not be read.
    #[error("cannot read the network file {path}: {source}")]
    ReadFile {
        /// The path.
        path: String,
        /// Why not.
        source: std::io::Error,
    },
    /// The network file is not right.
    #[error(transparent)]
    NetworkFile(#[from] crate::network_file::FileError),
    /// A safety function of the network file has no reaction-time bound.
    #[error(transparent)]
    Sfrt(#[from] crate::calc::sfrt::SfrtError),
    /// The interface specification on the command line is not one this tool knows.
    #[error("{0}")]
    Usage(String),
    /// The monitor stopped: its log, recording, terminal or bus failed.
    #[error(transparent)]
    Monitor(#[from] crate::monitor::MonitorError),
    /// An LSS service failed (CiA 305); the message names the node and the step.
    #[error(transparent)]
    Lss(#[from] crate::lss::LssError),
    /// The result could not be written as JSON (`--json`).
    #[error(
        "the result could not be written as JSON ({0}), so none was printed; run the command without --json to read it"
    )]
    Json(serde_json::Error),
}
