//! The device's object dictionary as the SDO server sees it: communication objects
//! (0x1000..0x1018), the GFC parameter (0x1300), the objects of the safety protocol in the
//! slot ([`SafetyProtocol::owns`]: for the SRDO table 0x1301..0x13FF and the double-reception
//! counters, [`super::DOUBLE_RECEPTION_INDEX`]), the access control's objects (0x5C10..0x5C13,
//! [`super::access`]) and the application objects. Writes that change the safety configuration
//! pass the access control first (SC_REQ_43).

use super::access::AccessControl;
use super::{Core, Event, persist};
use crate::canopen::nmt::NmtState;
use crate::canopen::od::{AbortCode, Address, ObjectDictionary};
use crate::canopen::storage::{Flash, StorageError};
use crate::node::slot::SafetyProtocol;
use crate::process_image::Access;
use crate::safety::gfc;

/// The signature "save" that 0x1010 expects (CiA 301 7.5.2.13).
const SAVE: u32 = u32::from_le_bytes(*b"save");
/// The signature "load" that 0x1011 expects (CiA 301 7.5.2.14).
const LOAD: u32 = u32::from_le_bytes(*b"load");

/// Copies `bytes` into `buf`, or answers that `buf` is too small.
pub(super) fn put(buf: &mut [u8], bytes: &[u8]) -> Result<usize, AbortCode> {
    let target = buf.get_mut(..bytes.len()).ok_or(AbortCode::OutOfMemory)?;
    target.copy_from_slice(bytes);
    Ok(bytes.len())
}

/// `data` as exactly `L` bytes, or the length abort code (CiA 301 0607 0012h / 0607 0013h).
pub(super) fn exact<const L: usize>(data: &[u8]) -> Result<[u8; L], AbortCode> {
    if data.len() > L {
        return Err(AbortCode::LengthTooHigh);
    }
    <[u8; L]>::try_from(data).map_err(|_| AbortCode::LengthTooLow)
}

/// Whether `data` is exactly `len` bytes, or the length abort code (CiA 301 0607 0012h /
/// 0607 0013h): [`exact`] for a length known only at run time. `exact` keeps its own
/// comparison: written through this one it is inlined larger at its many call sites (measured
/// by `cargo xtask footprint`: docs/footprint.md, "History").
pub(super) fn length(data: &[u8], len: usize) -> Result<(), AbortCode> {
    match data.len().cmp(&len) {
        core::cmp::Ordering::Greater => Err(AbortCode::LengthTooHigh),
        core::cmp::Ordering::Less => Err(AbortCode::LengthTooLow),
        core::cmp::Ordering::Equal => Ok(()),
    }
}

impl<F: Flash, P: SafetyProtocol> ObjectDictionary for Core<F, P> {
    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let Address { index, sub } = address;
        match index {
            0x1000 if sub == 0 => put(buf, &self.shell.config.device_type.to_le_bytes()),
            0x1001 if sub == 0 => put(buf, &[self.shell.error_register]),
            0x1008 if sub == 0 => put(buf, self.shell.config.device_name.as_bytes()),
            0x1010 | 0x1011 => match sub {
                0 => put(buf, &[1]),
                // Bit 0: the device saves (restores) parameters on command.
                1 => put(buf, &1u32.to_le_bytes()),
                _ => Err(AbortCode::NoSubIndex),
            },
            0x1017 if sub == 0 => put(buf, &self.heartbeat.period_ms().to_le_bytes()),
            0x1018 => match sub {
                0 => put(buf, &[4]),
                1..=4 => put(
                    buf,
                    &self.shell.config.identity[usize::from(sub) - 1].to_le_bytes(),
                ),
                _ => Err(AbortCode::NoSubIndex),
            },
            gfc::GFC_PARAMETER if sub == 0 => put(buf, &[self.gfc_parameter]),
            0x1000 | 0x1001 | 0x1008 | 0x1017 | 0x1300 => Err(AbortCode::NoSubIndex),
            index if self.protocol.owns(index) => self.protocol.read(address, buf),
            index if AccessControl::<P::Signatures>::owns(index) => {
                self.access.read(address, self.now, buf)
            }
            0x2000..=0x9FFF => self.image.read(address, buf),
            _ => Err(AbortCode::NoObject),
        }
    }

    fn write(&mut self, address: Address, data: &[u8]) -> Result<(), AbortCode> {
        let Address { index, sub } = address;
        let operational = self.shell.state == NmtState::Operational;
        if !operational {
            // SC_REQ_43; in Operational the rules below refuse with 0800 0022h regardless.
            self.access.check_write::<P>(index, self.now)?;
        }
        match index {
            0x1000 | 0x1001 | 0x1008 | 0x1018 => {
                let mut scratch = [0u8; 64];
                self.read(address, &mut scratch)?;
                Err(AbortCode::ReadOnly)
            }
            0x1010 | 0x1011 => match sub {
                0 => Err(AbortCode::ReadOnly),
                // In Operational the parameters cannot change (EN 50325-5 8.2.2), so there is
                // nothing new to store, and programming flash holds the processor word by
                // word while the safety protocol runs: refused, and the configuration tool
                // stores in Pre-Operational.
                1 if operational => Err(AbortCode::DeviceState),
                1 => {
                    let signature = u32::from_le_bytes(exact(data)?);
                    if index == 0x1010 {
                        self.store(signature)
                    } else {
                        self.restore_defaults(signature)
                    }
                }
                _ => Err(AbortCode::NoSubIndex),
            },
            0x1017 if sub == 0 => {
                let period = u16::from_le_bytes(exact(data)?);
                self.heartbeat.set_period(period, self.now);
                Ok(())
            }
            gfc::GFC_PARAMETER if sub == 0 => {
                // EN 50325-5 8.2.2: the GFC parameter stays writable in Operational. It only
                // indicates (6.4.2.1): 0 clears the indication, 1 changes nothing and never
                // sends a GFC (see `gfc::GFC_PARAMETER` for other stacks' reading).
                match exact::<1>(data)? {
                    [gfc::GFC_NOT_VALID] => self.gfc_parameter = gfc::GFC_NOT_VALID,
                    [gfc::GFC_VALID] => {}
                    _ => return Err(AbortCode::ValueTooHigh),
                }
                Ok(())
            }
            0x1017 | 0x1300 => Err(AbortCode::NoSubIndex),
            index if self.protocol.owns(index) => {
                self.protocol
                    .write(address, data, &self.image, operational)?;
                if P::needs_unlock(index) {
                    // SC_REQ_43: a write that leaves the configuration validated validates it
                    // (every other accepted write withdraws the validation).
                    if let Some(signatures) = self.protocol.validated_signatures() {
                        self.access.record_validation(signatures);
                    }
                }
                Ok(())
            }
            index if AccessControl::<P::Signatures>::owns(index) => {
                self.access.write(address, data, self.now)
            }
            0x2000..=0x9FFF => {
                let (object, span) =
                    self.image
                        .find(address)
                        .ok_or(if self.image.has_index(index) {
                            if sub == 0 {
                                AbortCode::ReadOnly
                            } else {
                                AbortCode::NoSubIndex
                            }
                        } else {
                            AbortCode::NoObject
                        })?;
                if object.access == Access::ReadOnly {
                    return Err(AbortCode::ReadOnly);
                }
                if operational {
                    // Application safety values change only through SRDOs or the application
                    // in Operational.
                    return Err(AbortCode::DeviceState);
                }
                if data.len() != usize::from(object.len) {
                    return Err(if data.len() > usize::from(object.len) {
                        AbortCode::LengthTooHigh
                    } else {
                        AbortCode::LengthTooLow
                    });
                }
                self.image.set(span, data);
                Ok(())
            }
            _ => Err(AbortCode::NoObject),
        }
    }
}

impl<F: Flash, P: SafetyProtocol> Core<F, P> {
    /// 0x1010 sub-index 1: store all parameters (CiA 301 7.5.2.13).
    fn store(&mut self, signature: u32) -> Result<(), AbortCode> {
        if signature != SAVE {
            return Err(AbortCode::CannotStore);
        }
        persist::store(
            &mut self.flash,
            &self.protocol,
            self.heartbeat.period_ms(),
            self.shell.config.node_id,
            self.access.persisted(),
            #[cfg(feature = "lss")]
            self.stored_lss,
        )
        .map_err(|error| {
            self.deferred_event = Some(Event::StorageFailed(error));
            storage_abort(error)
        })
    }

    /// 0x1011 sub-index 1: restore default parameters at the next reset (CiA 301 7.5.2.14).
    fn restore_defaults(&mut self, signature: u32) -> Result<(), AbortCode> {
        if signature != LOAD {
            return Err(AbortCode::CannotStore);
        }
        persist::restore_defaults::<_, P>(
            &mut self.flash,
            self.shell.config.node_id,
            self.access.persisted(),
            #[cfg(feature = "lss")]
            self.stored_lss,
        )
        .map_err(|error| {
            self.deferred_event = Some(Event::StorageFailed(error));
            storage_abort(error)
        })
    }
}

/// The abort code of a failed store or restore (0x1010, 0x1011): 0800 0022h when the medium
/// refused it for the device's state (the free slot is erased at the next start-up,
/// [`StorageError::NotErased`]), 0606 0000h for every failure of the medium itself.
fn storage_abort(error: StorageError) -> AbortCode {
    match error {
        StorageError::NotErased => AbortCode::DeviceState,
        StorageError::TooLarge
        | StorageError::OutOfBounds
        | StorageError::Medium
        | StorageError::VerifyFailed
        | StorageError::Corrupt
        | StorageError::PowerLost => AbortCode::HardwareError,
    }
}
