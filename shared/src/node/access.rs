//! Protection of the safety configuration against unauthorised change (SC_REQ_43): a device
//! secret, a time-limited unlock, a growing lockout after failed attempts, and the audit
//! record of validated changes.
//!
//! # What is guarded
//! The access control is the device shell's ([`super::Device`]): it guards every SDO write to
//! 0x1010 (store), to 0x1011 (restore defaults), to the objects of the safety protocol in the
//! slot that are its safety configuration ([`SafetyProtocol::needs_unlock`]; for the SRDO
//! table 0x1301..=0x1340, 0x1381..=0x13C0, 0x13FE and 0x13FF), and the setting of a new
//! secret, once a secret is set ([`guards`]).
//! A device with no secret (a new device, or one whose parameter flash was erased) is *open*:
//! every such write is allowed, so the first configuration needs nothing but the tool.
//!
//! # The objects (manufacturer-specific area, EN 50325-5 leaves 2000h..5FFFh to the maker)
//! | object | sub | what | access |
//! |---|---|---|---|
//! | [`ACCESS_INDEX`] 5C10h | 0 | highest sub-index, 5 | ro |
//! | | 1 | unlock: the secret, 1..=[`MAX_SECRET`] bytes | wo |
//! | | 2 | set the secret: [`SALT_LEN`] bytes of salt, then the new secret ([`MIN_SECRET`]..=[`MAX_SECRET`] bytes) | wo |
//! | | 3 | [`AccessState`] (UNSIGNED8); writing 1 locks at once | rw |
//! | | 4 | failed attempts since power-on (UNSIGNED16, saturating) | ro |
//! | | 5 | remaining time of the unlock or of the lockout, ms (UNSIGNED32) | ro |
//! | [`CHANGE_COUNTER_INDEX`] 5C11h | 0 | validated changes of the configuration (UNSIGNED32) | ro |
//! | [`SIGNATURES_BEFORE_INDEX`] 5C12h | 1..=N | signature n of the protocol's configuration (of SRDO n) before the last validated change | ro |
//! | [`SIGNATURES_AFTER_INDEX`] 5C13h | 1..=N | signature n after it | ro |
//!
//! The signatures are the protocol's ([`SafetyProtocol::validated_signatures`]): the shell
//! records a change when, after an accepted write to the protocol's safety configuration, the
//! protocol reports its configuration validated with signatures other than the last recorded.
//!
//! The secret itself is never kept: only `SHA-256(salt ‖ secret)` and the salt, stored with the
//! parameters (`persist`), and neither is readable over SDO (sub-indices 1 and 2 are
//! write-only, 0601 0001h). The salt comes from the tool, which draws it from the operating
//! system's random source; the device has none.
//!
//! # Setting and resetting the secret
//! On an open device, or while unlocked, a write to 5C10h:02h sets the secret and unlocks the
//! device for [`UNLOCK_PERIOD`], so that the 0x1010 store that makes it permanent is allowed;
//! until that store, a reset forgets it. Nothing over the bus removes a secret once stored
//! (0x1011 keeps it, see `persist`). Resetting it is a deliberate physical action: erasing the
//! parameter flash (sectors 10 and 11) with the flashing tool, which leaves a new, open device
//! with its default configuration (not validated: the safe state until commissioned again).
//!
//! # Unlock and lockout
//! A correct secret written to 5C10h:01h unlocks for [`UNLOCK_PERIOD`] of the caller's `now`;
//! the unlock ends earlier at any NMT command but "enter pre-operational" (start, stop, both
//! resets), and on a write of 1 to 5C10h:03h. A wrong secret counts a failure and locks out
//! for [`lockout`] of the failures so far (1 s, doubling, at most [`MAX_LOCKOUT`]); an attempt
//! during a lockout is refused without being compared or counted. A correct secret clears the
//! count. The count and the lockout live in RAM and survive NMT reset node and reset
//! communication (the resets anyone on the bus can send); a power cycle clears them, which
//! needs the same physical access as erasing the flash.
//!
//! # Abort codes (CiA 301 7.2.4.3.17), one per reason
//! - A guarded write while locked (or after the unlock expired): 0601 0000h "unsupported
//!   access to an object". The object is writable and the data may be fine; what is missing is
//!   the right to write it, which is an access property of the object, not a device state
//!   (0800 0022h stays the answer for Operational, where nobody may write) and not a property
//!   of the data.
//! - A wrong secret: 0800 0020h "data cannot be transferred or stored to the application":
//!   the request was well formed and the application refused the data, without saying more.
//! - An unlock attempt during a lockout: 0800 0022h "because of the present device state": the
//!   data is not even looked at; the same attempt later may succeed.
//! - A secret of the wrong length: 0607 0012h / 0607 0013h.
//!
//! Both channels of a dual-channel node run this same code on the same SDO requests, each on
//! its own clock. At the very edge of the unlock period one channel may accept a write the
//! other refuses; their configurations then differ, the configuration digests on the link
//! differ, and the node goes to the safe state at NMT start: the disagreement is fail-safe.

use sha2::{Digest, Sha256};

use super::slot::SafetyProtocol;
use crate::canopen::od::{AbortCode, Address};
use crate::time::{Duration, Instant, expired};

/// Object of the unlock, the secret, the state, the failed attempts and the remaining time.
pub const ACCESS_INDEX: u16 = 0x5C10;
/// Object of the count of validated configuration changes.
pub const CHANGE_COUNTER_INDEX: u16 = 0x5C11;
/// Object of the signatures (one per SRDO, as 0x13FF) before the last validated change.
pub const SIGNATURES_BEFORE_INDEX: u16 = 0x5C12;
/// Object of the signatures (one per SRDO, as 0x13FF) after the last validated change.
pub const SIGNATURES_AFTER_INDEX: u16 = 0x5C13;

/// Every object of this module; no application object may use them.
pub const INDICES: [u16; 4] = [
    ACCESS_INDEX,
    CHANGE_COUNTER_INDEX,
    SIGNATURES_BEFORE_INDEX,
    SIGNATURES_AFTER_INDEX,
];

/// The shell's own objects whose writes need the unlock: 0x1010 (store) and 0x1011 (restore
/// defaults).
pub const SHELL_GUARDED: [u16; 2] = [0x1010, 0x1011];

/// `true` for the objects whose writes change the safety configuration of a device running
/// protocol `P`: [`SHELL_GUARDED`] and those `P` says need the unlock (an index among them
/// that the device does not have answers its own abort code, locked or not).
#[must_use]
pub fn guards<P: SafetyProtocol>(index: u16) -> bool {
    SHELL_GUARDED.contains(&index) || P::needs_unlock(index)
}

/// Sub-indices of [`ACCESS_INDEX`].
pub mod sub {
    /// Write the secret to unlock.
    pub const UNLOCK: u8 = 1;
    /// Write salt and new secret to set the secret.
    pub const SET_SECRET: u8 = 2;
    /// Read the [`AccessState`](super::AccessState); write 1 to lock.
    pub const STATE: u8 = 3;
    /// Read the failed attempts since power-on.
    pub const FAILED_ATTEMPTS: u8 = 4;
    /// Read the remaining time of the unlock or the lockout, ms.
    pub const REMAINING_MS: u8 = 5;
}

/// Bytes of salt the tool sends ahead of a new secret (128 bits, NIST SP 800-132 5.1).
pub const SALT_LEN: usize = 16;
/// Fewest bytes of a new secret.
pub const MIN_SECRET: usize = 8;
/// Most bytes of a secret.
pub const MAX_SECRET: usize = 32;
/// How long an unlock lasts: long enough for the tool to configure, verify and store every
/// SRDO of the node over a slow bus (the whole procedure for 16 SRDOs is timed in
/// docs/performance.md), short enough that a forgotten unlock does not outlast the maintenance
/// visit.
pub const UNLOCK_PERIOD: Duration = Duration::from_millis(10 * 60 * 1000);
/// The longest lockout after failed attempts.
pub const MAX_LOCKOUT: Duration = Duration::from_millis(60 * 60 * 1000);

/// The lockout after the `failures`-th consecutive failed attempt: 1 s, 2 s, 4 s, … doubling,
/// at most [`MAX_LOCKOUT`] (reached at the 13th failure). Growing rather than fixed so that a
/// mistyped secret costs a second and guessing costs hours: after 20 failures a guesser gets
/// one attempt per hour.
#[must_use]
pub const fn lockout(failures: u16) -> Duration {
    if failures == 0 {
        return Duration::ZERO;
    }
    // 2^11 s < 3600 s < 2^12 s: beyond the 13th failure the cap holds, and the shift stays
    // far below 64 bits.
    let shift = if failures > 13 { 12 } else { failures - 1 };
    let millis = 1000u64 << shift;
    let cap = MAX_LOCKOUT.as_micros() / 1000;
    Duration::from_millis(if millis < cap { millis } else { cap })
}

/// Whether changes of the safety configuration are allowed now (5C10h:03h).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum AccessState {
    /// No secret is set: every change is allowed (a new device).
    Open = 0,
    /// A secret is set and the device is not unlocked.
    Locked = 1,
    /// Unlocked with the secret, until the unlock period ends or an NMT command.
    Unlocked = 2,
    /// Locked, and unlock attempts are refused until the lockout ends.
    LockedOut = 3,
}

/// The stored form of the secret: a salt and `SHA-256(salt ‖ secret)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Secret {
    /// The salt the tool sent with the secret.
    pub salt: [u8; SALT_LEN],
    /// `SHA-256(salt ‖ secret)`.
    pub hash: [u8; 32],
}

impl Secret {
    /// The stored form of `secret` under `salt`.
    fn new(salt: [u8; SALT_LEN], secret: &[u8]) -> Self {
        Secret {
            salt,
            hash: digest(&salt, secret),
        }
    }

    /// `true` when `candidate` is the secret. Every byte of the hash is compared whatever the
    /// first difference, so the answer's timing says nothing about where candidates differ
    /// (over an SDO exchange it could not be resolved anyway: a frame takes 100 µs or more).
    fn matches(&self, candidate: &[u8]) -> bool {
        let other = digest(&self.salt, candidate);
        self.hash
            .iter()
            .zip(other.iter())
            .fold(0u8, |difference, (a, b)| difference | (a ^ b))
            == 0
    }
}

/// `SHA-256(salt ‖ secret)`.
fn digest(salt: &[u8; SALT_LEN], secret: &[u8]) -> [u8; 32] {
    let mut hasher = Sha256::new();
    hasher.update(salt);
    hasher.update(secret);
    hasher.finalize().into()
}

/// The audit record: how many validated changes the configuration has seen, and the
/// protocol's signatures `S` (one per SRDO for the SRDO table) before and after the last one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Audit<S> {
    /// Validated changes since the parameter flash was erased (saturating).
    pub changes: u32,
    /// The signatures of the configuration validated before the last change (0: none was).
    pub before: S,
    /// The signatures of the configuration of the last validated change.
    pub after: S,
}

impl<S: Copy> Audit<S> {
    /// A device whose configuration was never validated, `none` being the protocol's
    /// [`SafetyProtocol::NO_SIGNATURES`].
    pub const fn none(none: S) -> Self {
        Audit {
            changes: 0,
            before: none,
            after: none,
        }
    }
}

/// What of the access control is stored with the parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Persisted<S> {
    /// The secret, if one is set.
    pub secret: Option<Secret>,
    /// The audit record.
    pub audit: Audit<S>,
}

impl<S: Copy> Persisted<S> {
    /// A new device: no secret, no validated change (`none`: the protocol's
    /// [`SafetyProtocol::NO_SIGNATURES`]).
    pub const fn new(none: S) -> Self {
        Persisted {
            secret: None,
            audit: Audit::none(none),
        }
    }
}

/// The access control of one device whose protocol's signatures are `S`. Sans-I/O: every
/// decision takes the caller's `now`.
#[derive(Clone, Debug)]
pub struct AccessControl<S> {
    persisted: Persisted<S>,
    /// The end of the unlock; `None` while locked.
    unlocked_until: Option<Instant>,
    /// Consecutive failed attempts since power-on (saturating).
    failures: u16,
    /// The end of the lockout (the past when there is none).
    locked_out_until: Instant,
}

impl<S: Copy + Eq + AsRef<[u16]>> AccessControl<S> {
    /// A device at power-on with nothing stored: open, no failures (`none`: the protocol's
    /// [`SafetyProtocol::NO_SIGNATURES`]).
    #[must_use]
    pub const fn new(none: S) -> Self {
        AccessControl {
            persisted: Persisted::new(none),
            unlocked_until: None,
            failures: 0,
            locked_out_until: Instant::ZERO,
        }
    }

    /// `true` for the objects this module answers.
    #[must_use]
    pub const fn owns(index: u16) -> bool {
        matches!(index, 0x5C10..=0x5C13)
    }

    /// The state at `now`.
    #[must_use]
    pub fn state(&self, now: Instant) -> AccessState {
        if self.persisted.secret.is_none() {
            AccessState::Open
        } else if self.unlocked_until.is_some_and(|end| !expired(end, now)) {
            AccessState::Unlocked
        } else if !expired(self.locked_out_until, now) {
            AccessState::LockedOut
        } else {
            AccessState::Locked
        }
    }

    /// Consecutive failed unlock attempts since power-on.
    #[must_use]
    pub fn failures(&self) -> u16 {
        self.failures
    }

    /// The audit record.
    #[must_use]
    pub fn audit(&self) -> &Audit<S> {
        &self.persisted.audit
    }

    /// What is stored with the parameters.
    #[must_use]
    pub fn persisted(&self) -> &Persisted<S> {
        &self.persisted
    }

    /// Takes over what was stored (at power-on and at every NMT reset); the unlock, the
    /// failures and the lockout are not stored and stay as they are.
    pub fn restore(&mut self, persisted: Persisted<S>) {
        self.persisted = persisted;
    }

    /// Ends the unlock (at NMT start, stop and the resets; on a write of 1 to 5C10h:03h).
    pub fn lock(&mut self) {
        self.unlocked_until = None;
    }

    /// Whether a write to `index` of a device running protocol `P` may go on at `now`: `Ok`
    /// for objects not guarded ([`guards`]), on an open device and while unlocked; 0601 0000h
    /// otherwise (see the module's abort codes).
    pub fn check_write<P: SafetyProtocol>(
        &self,
        index: u16,
        now: Instant,
    ) -> Result<(), AbortCode> {
        if !guards::<P>(index) {
            return Ok(());
        }
        match self.state(now) {
            AccessState::Open | AccessState::Unlocked => Ok(()),
            AccessState::Locked | AccessState::LockedOut => Err(AbortCode::UnsupportedAccess),
        }
    }

    /// A validated change (0x13FE = A5h accepted) with these signatures: counted, with the
    /// previous validated signatures as "before", unless the signatures are those of the last
    /// validated change (validating the same configuration again is not a change).
    pub fn record_validation(&mut self, signatures: S) {
        let audit = &mut self.persisted.audit;
        if audit.changes != 0 && audit.after == signatures {
            return;
        }
        audit.changes = audit.changes.saturating_add(1);
        audit.before = audit.after;
        audit.after = signatures;
    }

    /// SDO read of one of the objects [`AccessControl::owns`].
    pub fn read(&self, address: Address, now: Instant, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let Address { index, sub } = address;
        let audit = &self.persisted.audit;
        // Every entry is an unsigned number of 1, 2 or 4 bytes: one copy below for all.
        let (value, len): (u32, usize) = match (index, sub) {
            (ACCESS_INDEX, 0) => (u32::from(sub::REMAINING_MS), 1),
            (ACCESS_INDEX, sub::UNLOCK | sub::SET_SECRET) => return Err(AbortCode::WriteOnly),
            (ACCESS_INDEX, sub::STATE) => (self.state(now) as u32, 1),
            (ACCESS_INDEX, sub::FAILED_ATTEMPTS) => (u32::from(self.failures), 2),
            (ACCESS_INDEX, sub::REMAINING_MS) => (self.remaining_ms(now), 4),
            (CHANGE_COUNTER_INDEX, 0) => (audit.changes, 4),
            // At most 64 signatures (the SRDO table's largest), so the count fits its byte.
            (SIGNATURES_BEFORE_INDEX | SIGNATURES_AFTER_INDEX, 0) => {
                (audit.after.as_ref().len() as u32, 1)
            }
            (SIGNATURES_BEFORE_INDEX | SIGNATURES_AFTER_INDEX, n) => {
                let signatures = if index == SIGNATURES_BEFORE_INDEX {
                    audit.before.as_ref()
                } else {
                    audit.after.as_ref()
                };
                let signature = usize::from(n)
                    .checked_sub(1)
                    .and_then(|slot| signatures.get(slot))
                    .ok_or(AbortCode::NoSubIndex)?;
                (u32::from(*signature), 2)
            }
            (ACCESS_INDEX | CHANGE_COUNTER_INDEX, _) => return Err(AbortCode::NoSubIndex),
            _ => return Err(AbortCode::NoObject),
        };
        let bytes = value.to_le_bytes();
        let (Some(target), Some(source)) = (buf.get_mut(..len), bytes.get(..len)) else {
            return Err(AbortCode::OutOfMemory);
        };
        target.copy_from_slice(source);
        Ok(len)
    }

    /// SDO write of one of the objects [`AccessControl::owns`] at `now`.
    pub fn write(&mut self, address: Address, data: &[u8], now: Instant) -> Result<(), AbortCode> {
        let Address { index, sub } = address;
        if index != ACCESS_INDEX {
            // Answer existence first, then refuse: the audit record is read-only.
            let mut scratch = [0u8; 4];
            self.read(address, now, &mut scratch)?;
            return Err(AbortCode::ReadOnly);
        }
        match sub {
            sub::UNLOCK => self.unlock(data, now),
            sub::SET_SECRET => self.set_secret(data, now),
            sub::STATE => match data {
                [1] => {
                    self.lock();
                    Ok(())
                }
                [_] => Err(AbortCode::InvalidValue),
                [] => Err(AbortCode::LengthTooLow),
                _ => Err(AbortCode::LengthTooHigh),
            },
            0 | sub::FAILED_ATTEMPTS | sub::REMAINING_MS => Err(AbortCode::ReadOnly),
            _ => Err(AbortCode::NoSubIndex),
        }
    }

    /// 5C10h:01h: compares `candidate` with the secret, unless locked out.
    fn unlock(&mut self, candidate: &[u8], now: Instant) -> Result<(), AbortCode> {
        if candidate.len() > MAX_SECRET {
            return Err(AbortCode::LengthTooHigh);
        }
        if candidate.is_empty() {
            return Err(AbortCode::LengthTooLow);
        }
        let Some(secret) = self.persisted.secret else {
            // Open: nothing to prove, and nothing changes (the device stays open).
            return Ok(());
        };
        if !expired(self.locked_out_until, now) {
            return Err(AbortCode::DeviceState);
        }
        if secret.matches(candidate) {
            self.failures = 0;
            self.unlocked_until = Some(now + UNLOCK_PERIOD);
            Ok(())
        } else {
            self.failures = self.failures.saturating_add(1);
            self.locked_out_until = now + lockout(self.failures);
            self.unlocked_until = None;
            Err(AbortCode::CannotStore)
        }
    }

    /// 5C10h:02h: salt, then the new secret; on an open device or while unlocked. Unlocks for
    /// a full [`UNLOCK_PERIOD`] so that the store (0x1010) that keeps it can follow.
    fn set_secret(&mut self, data: &[u8], now: Instant) -> Result<(), AbortCode> {
        match self.state(now) {
            AccessState::Open | AccessState::Unlocked => {}
            AccessState::Locked | AccessState::LockedOut => {
                return Err(AbortCode::UnsupportedAccess);
            }
        }
        if data.len() > SALT_LEN + MAX_SECRET {
            return Err(AbortCode::LengthTooHigh);
        }
        let (salt, secret) = data
            .split_first_chunk::<SALT_LEN>()
            .ok_or(AbortCode::LengthTooLow)?;
        if secret.len() < MIN_SECRET {
            return Err(AbortCode::LengthTooLow);
        }
        self.persisted.secret = Some(Secret::new(*salt, secret));
        self.unlocked_until = Some(now + UNLOCK_PERIOD);
        Ok(())
    }

    /// 5C10h:05h: what is left of the unlock, or of the lockout, in ms (saturating).
    fn remaining_ms(&self, now: Instant) -> u32 {
        let end = match self.state(now) {
            AccessState::Unlocked => self.unlocked_until.unwrap_or(now),
            AccessState::LockedOut => self.locked_out_until,
            AccessState::Open | AccessState::Locked => now,
        };
        // Both periods are below 2^32 µs (71 min), so the remainder fits a u32 and the
        // division is a 32-bit one (a 64-bit division links compiler_builtins' general routine
        // on Cortex-M4, docs/footprint.md); saturating at u32::MAX µs keeps a longer one
        // readable as ~71 min.
        let micros = u32::try_from(end.saturating_since(now).as_micros()).unwrap_or(u32::MAX);
        micros.div_ceil(1000)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::node::SrdoTable;

    /// The protocol of the node these tests stand for: an SRDO table of 2 SRDOs.
    type Table = SrdoTable<2>;
    /// Its access control.
    type Access = AccessControl<[u16; 2]>;

    const SALT: [u8; SALT_LEN] = *b"0123456789abcdef";
    const SECRET: &[u8] = b"correct horse";

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    fn set(access: &mut Access, now: Instant) {
        let mut data = [0u8; SALT_LEN + 13];
        data[..SALT_LEN].copy_from_slice(&SALT);
        data[SALT_LEN..].copy_from_slice(SECRET);
        access
            .write(Address::new(ACCESS_INDEX, sub::SET_SECRET), &data, now)
            .unwrap();
    }

    fn locked() -> Access {
        let mut access = Access::new([0; 2]);
        set(&mut access, at(0));
        access.lock();
        access
    }

    fn unlock(access: &mut Access, secret: &[u8], now: Instant) -> Result<(), AbortCode> {
        access.write(Address::new(ACCESS_INDEX, sub::UNLOCK), secret, now)
    }

    #[test]
    fn sc_req_43_a_new_device_is_open_for_commissioning() {
        let access = Access::new([0; 2]);
        assert_eq!(access.state(at(0)), AccessState::Open);
        for index in [0x1010, 0x1011, 0x1301, 0x1381, 0x13FE, 0x13FF] {
            assert_eq!(access.check_write::<Table>(index, at(0)), Ok(()));
        }
    }

    #[test]
    fn sc_req_43_the_stored_form_is_the_salted_sha_256() {
        let mut access = Access::new([0; 2]);
        set(&mut access, at(0));
        let secret = access.persisted().secret.unwrap();
        assert_eq!(secret.salt, SALT);
        let mut hasher = Sha256::new();
        hasher.update(SALT);
        hasher.update(SECRET);
        assert_eq!(secret.hash, <[u8; 32]>::from(hasher.finalize()));
        // Another salt, another hash for the same secret.
        assert_ne!(Secret::new([0; SALT_LEN], SECRET).hash, secret.hash);
    }

    #[test]
    fn sc_req_43_locked_refuses_every_guarded_write_and_nothing_else() {
        let access = locked();
        assert_eq!(access.state(at(1)), AccessState::Locked);
        for index in [
            0x1010, 0x1011, 0x1301, 0x1340, 0x1381, 0x13C0, 0x13FE, 0x13FF,
        ] {
            assert_eq!(
                access.check_write::<Table>(index, at(1)),
                Err(AbortCode::UnsupportedAccess),
                "{index:04X}"
            );
        }
        for index in [0x1017, 0x1300, 0x2000, 0x6000] {
            assert_eq!(
                access.check_write::<Table>(index, at(1)),
                Ok(()),
                "{index:04X}"
            );
        }
    }

    #[test]
    fn sc_req_43_the_guarded_objects_are_exactly_the_safety_configuration_store_and_restore() {
        use crate::safety::config::SafetyConfig;
        for index in 0..=u16::MAX {
            assert_eq!(
                guards::<Table>(index),
                SafetyConfig::<2>::owns(index) || index == 0x1010 || index == 0x1011,
                "{index:04X}"
            );
        }
    }

    #[test]
    fn sc_req_43_the_secret_is_never_readable() {
        let access = locked();
        let mut buf = [0u8; 64];
        for sub in [sub::UNLOCK, sub::SET_SECRET] {
            assert_eq!(
                access.read(Address::new(ACCESS_INDEX, sub), at(1), &mut buf),
                Err(AbortCode::WriteOnly)
            );
        }
    }

    #[test]
    fn sc_req_43_the_unlock_lasts_its_period_and_ends_at_lock() {
        let mut access = locked();
        assert_eq!(unlock(&mut access, SECRET, at(1_000)), Ok(()));
        let end = at(1_000) + UNLOCK_PERIOD;
        let just_before = Instant::from_micros(end.as_micros() - 1);
        assert_eq!(access.check_write::<Table>(0x1301, just_before), Ok(()));
        let mut buf = [0u8; 4];
        access
            .read(
                Address::new(ACCESS_INDEX, sub::REMAINING_MS),
                at(1_000),
                &mut buf,
            )
            .unwrap();
        assert_eq!(
            u64::from(u32::from_le_bytes(buf)) * 1000,
            UNLOCK_PERIOD.as_micros()
        );
        // The period ends at its deadline itself.
        assert_eq!(access.state(end), AccessState::Locked);
        assert_eq!(
            access.check_write::<Table>(0x1301, end),
            Err(AbortCode::UnsupportedAccess)
        );

        assert_eq!(unlock(&mut access, SECRET, end), Ok(()));
        access.lock();
        assert_eq!(
            access.check_write::<Table>(0x1301, end),
            Err(AbortCode::UnsupportedAccess)
        );
        assert_eq!(unlock(&mut access, SECRET, end), Ok(()));
        access
            .write(Address::new(ACCESS_INDEX, sub::STATE), &[1], end)
            .unwrap();
        assert_eq!(access.state(end), AccessState::Locked);
    }

    #[test]
    fn sc_req_43_a_wrong_secret_is_refused_counted_and_locks_out() {
        let mut access = locked();
        assert_eq!(
            unlock(&mut access, b"wrong", at(10)),
            Err(AbortCode::CannotStore)
        );
        assert_eq!(access.failures(), 1);
        assert_eq!(access.state(at(10)), AccessState::LockedOut);
        // During the lockout even the right secret is refused, and not counted.
        assert_eq!(
            unlock(&mut access, SECRET, at(500)),
            Err(AbortCode::DeviceState)
        );
        assert_eq!(access.failures(), 1);
        assert_eq!(
            access.check_write::<Table>(0x13FE, at(500)),
            Err(AbortCode::UnsupportedAccess)
        );
        // At its end the right secret unlocks, and clears the count.
        assert_eq!(unlock(&mut access, SECRET, at(1_010)), Ok(()));
        assert_eq!(access.failures(), 0);
    }

    #[test]
    fn sc_req_43_the_lockout_grows_with_failures_to_its_cap() {
        let mut access = locked();
        let mut now = at(0);
        let mut previous = Duration::ZERO;
        for failure in 1..=20u16 {
            assert_eq!(
                unlock(&mut access, b"guess", now),
                Err(AbortCode::CannotStore)
            );
            let wait = lockout(failure);
            assert!(wait.as_micros() >= previous.as_micros());
            assert!(wait.as_micros() <= MAX_LOCKOUT.as_micros());
            let end = now + wait;
            let just_before = Instant::from_micros(end.as_micros() - 1);
            assert_eq!(
                unlock(&mut access, b"guess", just_before),
                Err(AbortCode::DeviceState)
            );
            now = end;
            previous = wait;
        }
        assert_eq!(lockout(1), Duration::from_millis(1_000));
        assert_eq!(lockout(2), Duration::from_millis(2_000));
        assert_eq!(lockout(12), Duration::from_millis(2_048_000));
        assert_eq!(lockout(13), MAX_LOCKOUT);
        assert_eq!(lockout(u16::MAX), MAX_LOCKOUT);
        assert_eq!(access.failures(), 20);
    }

    #[test]
    fn sc_req_43_setting_a_secret_needs_an_open_or_unlocked_device() {
        let mut access = locked();
        let mut data = [7u8; SALT_LEN + MIN_SECRET];
        assert_eq!(
            access.write(Address::new(ACCESS_INDEX, sub::SET_SECRET), &data, at(1)),
            Err(AbortCode::UnsupportedAccess)
        );
        unlock(&mut access, SECRET, at(1)).unwrap();
        data[0] = 1;
        access
            .write(Address::new(ACCESS_INDEX, sub::SET_SECRET), &data, at(2))
            .unwrap();
        access.lock();
        assert_eq!(
            unlock(&mut access, SECRET, at(3)),
            Err(AbortCode::CannotStore),
            "the old secret no longer unlocks"
        );
        assert_eq!(unlock(&mut access, &[7; MIN_SECRET], at(2_000)), Ok(()));
    }

    #[test]
    fn sc_req_43_secret_lengths_out_of_range_are_refused_by_length() {
        let mut access = Access::new([0; 2]);
        let address = Address::new(ACCESS_INDEX, sub::SET_SECRET);
        let data = [1u8; SALT_LEN + MAX_SECRET + 1];
        assert_eq!(
            access.write(address, &data[..SALT_LEN + MIN_SECRET - 1], at(0)),
            Err(AbortCode::LengthTooLow)
        );
        assert_eq!(
            access.write(address, &data[..SALT_LEN - 1], at(0)),
            Err(AbortCode::LengthTooLow)
        );
        assert_eq!(
            access.write(address, &data, at(0)),
            Err(AbortCode::LengthTooHigh)
        );
        assert_eq!(access.state(at(0)), AccessState::Open);
        assert_eq!(
            unlock(&mut access, &data[..MAX_SECRET + 1], at(0)),
            Err(AbortCode::LengthTooHigh)
        );
        assert_eq!(
            unlock(&mut access, &[], at(0)),
            Err(AbortCode::LengthTooLow)
        );
    }

    #[test]
    fn sc_req_43_the_audit_records_each_validated_change() {
        let mut access = Access::new([0; 2]);
        access.record_validation([0x1111, 0x2222]);
        access.record_validation([0x1111, 0x2222]);
        assert_eq!(
            *access.audit(),
            Audit {
                changes: 1,
                before: [0, 0],
                after: [0x1111, 0x2222],
            }
        );
        access.record_validation([0x3333, 0x2222]);
        assert_eq!(
            *access.audit(),
            Audit {
                changes: 2,
                before: [0x1111, 0x2222],
                after: [0x3333, 0x2222],
            }
        );
        let mut buf = [0u8; 4];
        let read = |access: &Access, index, sub, buf: &mut [u8]| {
            access.read(Address::new(index, sub), at(0), buf)
        };
        assert_eq!(read(&access, CHANGE_COUNTER_INDEX, 0, &mut buf), Ok(4));
        assert_eq!(u32::from_le_bytes(buf), 2);
        assert_eq!(read(&access, SIGNATURES_BEFORE_INDEX, 0, &mut buf), Ok(1));
        assert_eq!(buf[0], 2);
        assert_eq!(read(&access, SIGNATURES_BEFORE_INDEX, 1, &mut buf), Ok(2));
        assert_eq!(u16::from_le_bytes([buf[0], buf[1]]), 0x1111);
        assert_eq!(read(&access, SIGNATURES_AFTER_INDEX, 1, &mut buf), Ok(2));
        assert_eq!(u16::from_le_bytes([buf[0], buf[1]]), 0x3333);
        assert_eq!(
            read(&access, SIGNATURES_AFTER_INDEX, 3, &mut buf),
            Err(AbortCode::NoSubIndex)
        );
        assert_eq!(
            access.write(Address::new(CHANGE_COUNTER_INDEX, 0), &[0; 4], at(0)),
            Err(AbortCode::ReadOnly)
        );
    }
}
