//! The node's protection of its safety configuration (SC_REQ_43) from the tool's side:
//! reading the secret without showing it, unlocking, setting a secret, and reading the audit
//! record. The objects and their rules are `shared::node::access`.
//!
//! The secret never appears on the command line (where `ps` and the shell history would show
//! it): it comes from a file (`--secret-file`, its first line), from the environment variable
//! [`SECRET_VARIABLE`], or from a prompt on the terminal without echo, in that order (for the
//! new secret of `set-secret`: `--new-secret-file`, [`NEW_SECRET_VARIABLE`], a prompt asked
//! twice). On the bus it travels in the clear, like every CAN frame: see
//! docs/access-protection.md for what that means.

use crate::client::Client;
use crate::error::ToolError;
use crate::transport::Transport;
use shared::canopen::od::{AbortCode, Address};
use shared::node::SrdoTable;
use shared::node::access::{
    ACCESS_INDEX, AccessState, CHANGE_COUNTER_INDEX, MAX_SECRET, MIN_SECRET, SALT_LEN,
    SIGNATURES_AFTER_INDEX, SIGNATURES_BEFORE_INDEX, guards, sub,
};
use zeroize::Zeroizing;

/// The environment variable the secret is taken from when it is set.
pub const SECRET_VARIABLE: &str = "SAFETY_CONFIG_SECRET";
/// The environment variable `set-secret` takes the new secret from when it is set.
pub const NEW_SECRET_VARIABLE: &str = "SAFETY_CONFIG_NEW_SECRET";

/// A device secret in memory, overwritten when dropped; its `Debug` shows no byte of it.
pub struct Secret(Zeroizing<Vec<u8>>);

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Secret({} bytes)", self.0.len())
    }
}

impl Secret {
    /// `bytes` as a secret, if its length is one the node takes (1..=[`MAX_SECRET`] bytes to
    /// unlock; a new secret must have at least [`MIN_SECRET`], see [`set_secret`]).
    pub fn new(bytes: Vec<u8>) -> Result<Self, ToolError> {
        let bytes = Zeroizing::new(bytes);
        if bytes.is_empty() || bytes.len() > MAX_SECRET {
            return Err(ToolError::Usage(format!(
                "the secret has {} bytes; the node takes 1 to {MAX_SECRET}",
                bytes.len()
            )));
        }
        Ok(Secret(bytes))
    }

    /// The secret's bytes.
    fn bytes(&self) -> &[u8] {
        &self.0
    }
}

/// Where the secret comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SecretSource {
    /// This environment variable.
    Environment(&'static str),
    /// The first line of this file.
    File(std::path::PathBuf),
    /// A prompt on the terminal, without echo.
    Prompt,
}

impl SecretSource {
    /// The file when given, else the environment variable `variable` when it is set, else
    /// the prompt.
    pub fn choose(file: Option<&std::path::Path>, variable: &'static str) -> Self {
        match file {
            Some(path) => SecretSource::File(path.to_owned()),
            None if std::env::var_os(variable).is_some() => SecretSource::Environment(variable),
            None => SecretSource::Prompt,
        }
    }

    /// Reads the secret; `what` names it in the prompt ("secret of node 33").
    pub fn read(&self, what: &str) -> Result<Secret, ToolError> {
        let text = Zeroizing::new(match self {
            SecretSource::Environment(variable) => std::env::var(variable).map_err(|_| {
                ToolError::Usage(format!("{variable} is not set or not UTF-8"))
            })?,
            SecretSource::File(path) => {
                let content = Zeroizing::new(std::fs::read_to_string(path).map_err(|source| {
                    ToolError::Usage(format!(
                        "cannot read the secret file {}: {source}",
                        path.display()
                    ))
                })?);
                content.lines().next().unwrap_or_default().to_owned()
            }
            SecretSource::Prompt => rpassword::prompt_password(format!("{what}: "))
                .map_err(|error| {
                    ToolError::Usage(format!(
                        "cannot read the {what} from the terminal ({error}); use the environment variable or the file option instead"
                    ))
                })?,
        });
        Secret::new(text.as_bytes().to_vec())
    }

    /// Reads a new secret; from the prompt twice, and refused when the two differ.
    pub fn read_new(&self, what: &str) -> Result<Secret, ToolError> {
        let first = self.read(what)?;
        if *self == SecretSource::Prompt {
            let again = self.read(&format!("{what} (again)"))?;
            if again.bytes() != first.bytes() {
                return Err(ToolError::Usage(
                    "the two entries of the new secret differ; nothing was changed".into(),
                ));
            }
        }
        Ok(first)
    }
}

/// Reads the node's [`AccessState`] (5C10h:03h). A node without the object (firmware before
/// the access control) is open.
pub fn state<T: Transport>(client: &mut Client<T>, node: u8) -> Result<AccessState, ToolError> {
    match client.read_unsigned(node, Address::new(ACCESS_INDEX, sub::STATE), 1) {
        Ok(0) => Ok(AccessState::Open),
        Ok(1) => Ok(AccessState::Locked),
        Ok(2) => Ok(AccessState::Unlocked),
        Ok(3) => Ok(AccessState::LockedOut),
        Ok(other) => Err(ToolError::Usage(format!(
            "node {node}: access state {other} (5C10h:03h) is not one this tool knows"
        ))),
        Err(ToolError::Aborted { code, .. }) if code == AbortCode::NoObject as u32 => {
            Ok(AccessState::Open)
        }
        Err(error) => Err(error),
    }
}

/// Milliseconds left of the node's unlock or lockout (5C10h:05h).
pub fn remaining_ms<T: Transport>(client: &mut Client<T>, node: u8) -> Result<u32, ToolError> {
    client.read_unsigned(node, Address::new(ACCESS_INDEX, sub::REMAINING_MS), 4)
}

/// Unlocks `node` with `secret` (5C10h:01h). A wrong secret and an attempt during a lockout
/// are errors of their own, with the lockout's remaining time.
pub fn unlock<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    secret: &Secret,
) -> Result<(), ToolError> {
    match client.write(
        node,
        Address::new(ACCESS_INDEX, sub::UNLOCK),
        secret.bytes(),
    ) {
        Ok(()) => Ok(()),
        Err(ToolError::Aborted { code, .. }) if code == AbortCode::CannotStore as u32 => {
            Err(ToolError::WrongSecret {
                node,
                lockout_ms: remaining_ms(client, node)?,
            })
        }
        Err(ToolError::Aborted { code, .. }) if code == AbortCode::DeviceState as u32 => {
            Err(ToolError::LockedOut {
                node,
                remaining_ms: remaining_ms(client, node)?,
            })
        }
        Err(error) => Err(error),
    }
}

/// `error`, or [`ToolError::Locked`] when it is the node's refusal of a guarded write
/// (0601 0000h on 0x1010, 0x1011 or the safety configuration): the sentence then says what to
/// do instead of quoting the abort code.
pub fn explain_refusal(error: ToolError) -> ToolError {
    match error {
        ToolError::Aborted {
            node, object, code, ..
        } if code == AbortCode::UnsupportedAccess as u32
            // The nodes this tool configures run the SRDO table; which of its objects are
            // guarded does not depend on its number of SRDOs.
            && guards::<SrdoTable<1>>(object.0.index) =>
        {
            ToolError::Locked { node }
        }
        other => other,
    }
}

/// Ends the unlock of `node` at once (5C10h:03h = 1).
pub fn lock<T: Transport>(client: &mut Client<T>, node: u8) -> Result<(), ToolError> {
    client.write(node, Address::new(ACCESS_INDEX, sub::STATE), &[1])
}

/// Sets the secret of `node` (5C10h:02h) with a fresh salt from the operating system and
/// stores it (0x1010): the node must be open (a new device) or unlocked. The store keeps
/// every parameter the node holds, as any 0x1010 does.
pub fn set_secret<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    secret: &Secret,
) -> Result<(), ToolError> {
    if secret.bytes().len() < MIN_SECRET {
        return Err(ToolError::Usage(format!(
            "a new secret needs at least {MIN_SECRET} bytes, this one has {}",
            secret.bytes().len()
        )));
    }
    let mut salt = [0u8; SALT_LEN];
    getrandom::fill(&mut salt).map_err(|error| {
        ToolError::Usage(format!(
            "the operating system gave no random salt ({error})"
        ))
    })?;
    set_secret_with_salt(client, node, secret, salt)
}

/// [`set_secret`] with a given salt (for tests: the salt must be random in use).
pub fn set_secret_with_salt<T: Transport>(
    client: &mut Client<T>,
    node: u8,
    secret: &Secret,
    salt: [u8; SALT_LEN],
) -> Result<(), ToolError> {
    let mut data = Zeroizing::new(Vec::with_capacity(SALT_LEN + secret.bytes().len()));
    data.extend_from_slice(&salt);
    data.extend_from_slice(secret.bytes());
    match client.write(node, Address::new(ACCESS_INDEX, sub::SET_SECRET), &data) {
        Err(ToolError::Aborted { code, .. }) if code == AbortCode::UnsupportedAccess as u32 => {
            return Err(ToolError::Locked { node });
        }
        result => result?,
    }
    client
        .write(node, crate::procedure::STORE_PARAMETERS, b"save")
        .map_err(|error| crate::procedure::explain_store_refusal(explain_refusal(error)))
}

/// The node's audit record: validated changes and the signatures before and after the last.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Audit {
    /// The node-ID.
    pub node: u8,
    /// Validated changes since the parameter flash was erased (5C11h).
    pub changes: u32,
    /// Per SRDO, its signature before the last validated change (5C12h).
    pub before: Vec<u16>,
    /// Per SRDO, its signature after it (5C13h).
    pub after: Vec<u16>,
}

/// Reads the audit record of `node`.
pub fn read_audit<T: Transport>(client: &mut Client<T>, node: u8) -> Result<Audit, ToolError> {
    let changes = client.read_unsigned(node, Address::new(CHANGE_COUNTER_INDEX, 0), 4)?;
    let mut signatures = |index: u16| -> Result<Vec<u16>, ToolError> {
        let count = client.read_unsigned(node, Address::new(index, 0), 1)? as u8;
        (1..=count)
            .map(|n| Ok(client.read_unsigned(node, Address::new(index, n), 2)? as u16))
            .collect()
    };
    Ok(Audit {
        node,
        changes,
        before: signatures(SIGNATURES_BEFORE_INDEX)?,
        after: signatures(SIGNATURES_AFTER_INDEX)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sc_req_43_a_secret_file_gives_its_first_line_and_wins_over_the_rest() {
        let path =
            std::env::temp_dir().join(format!("safety-config-secret-{}", std::process::id()));
        std::fs::write(&path, "line one secret\nsecond line\n").unwrap();
        let source = SecretSource::choose(Some(&path), SECRET_VARIABLE);
        assert_eq!(source, SecretSource::File(path.clone()));
        let secret = source.read("secret").unwrap();
        assert_eq!(secret.bytes(), b"line one secret");
        std::fs::remove_file(&path).unwrap();
        let error = source.read("secret").unwrap_err().to_string();
        assert!(error.starts_with("cannot read the secret file"), "{error}");
    }

    #[test]
    fn sc_req_43_a_secret_never_shows_in_debug_output() {
        let secret = Secret::new(b"do not print me".to_vec()).unwrap();
        assert_eq!(format!("{secret:?}"), "Secret(15 bytes)");
    }

    #[test]
    fn secret_lengths_the_node_refuses_are_refused_by_the_tool() {
        assert!(Secret::new(Vec::new()).is_err());
        assert!(Secret::new(vec![b'x'; MAX_SECRET + 1]).is_err());
        assert!(Secret::new(vec![b'x'; MAX_SECRET]).is_ok());
    }
}
