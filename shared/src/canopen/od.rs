//! Addressing objects, and the SDO abort codes every access can end in (EN 50325-4, CiA 301
//! 7.2.4.3.17).
//!
//! [`ObjectDictionary`] is the one contract between the SDO server and whoever owns the
//! values: a read fills a buffer, a write is all-or-nothing and either succeeds or names the
//! abort code that says why not.

/// An object dictionary entry: 16-bit index and 8-bit sub-index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Address {
    /// The object index, e.g. `0x1301`.
    pub index: u16,
    /// The sub-index, e.g. `0x05`.
    pub sub: u8,
}

impl Address {
    /// The entry `index`:`sub`.
    pub const fn new(index: u16, sub: u8) -> Self {
        Address { index, sub }
    }
}

/// Why an SDO transfer (or a local access through the same rules) was refused.
///
/// Each variant's value is the abort code sent on the bus; its doc comment is the message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u32)]
pub enum AbortCode {
    /// Toggle bit not alternated.
    ToggleBit = 0x0503_0000,
    /// SDO protocol timed out.
    Timeout = 0x0504_0000,
    /// Client/server command specifier not valid or unknown.
    InvalidCommand = 0x0504_0001,
    /// Out of memory.
    OutOfMemory = 0x0504_0005,
    /// Unsupported access to an object.
    UnsupportedAccess = 0x0601_0000,
    /// Attempt to read a write only object.
    WriteOnly = 0x0601_0001,
    /// Attempt to write a read only object.
    ReadOnly = 0x0601_0002,
    /// Object does not exist in the object dictionary.
    NoObject = 0x0602_0000,
    /// Object cannot be mapped to the PDO (here: to the SRDO in this direction).
    NotMappable = 0x0604_0041,
    /// The number and length of the objects to be mapped would exceed the PDO (SRDO) length.
    MappingTooLong = 0x0604_0042,
    /// General parameter incompatibility reason.
    ParameterIncompatible = 0x0604_0043,
    /// General internal incompatibility in the device.
    InternalIncompatible = 0x0604_0047,
    /// Access failed due to a hardware error.
    HardwareError = 0x0606_0000,
    /// Data type does not match, length of service parameter does not match.
    LengthMismatch = 0x0607_0010,
    /// Data type does not match, length of service parameter too high.
    LengthTooHigh = 0x0607_0012,
    /// Data type does not match, length of service parameter too low.
    LengthTooLow = 0x0607_0013,
    /// Sub-index does not exist.
    NoSubIndex = 0x0609_0011,
    /// Invalid value for parameter (download only).
    InvalidValue = 0x0609_0030,
    /// Value of parameter written too high (download only).
    ValueTooHigh = 0x0609_0031,
    /// Value of parameter written too low (download only).
    ValueTooLow = 0x0609_0032,
    /// General error.
    General = 0x0800_0000,
    /// Data cannot be transferred or stored to the application.
    CannotStore = 0x0800_0020,
    /// Data cannot be transferred or stored to the application because of local control.
    LocalControl = 0x0800_0021,
    /// Data cannot be transferred or stored to the application because of the present device
    /// state.
    DeviceState = 0x0800_0022,
}

impl AbortCode {
    /// Every abort code this crate can send, for tests and tools.
    pub const ALL: [AbortCode; 24] = [
        AbortCode::ToggleBit,
        AbortCode::Timeout,
        AbortCode::InvalidCommand,
        AbortCode::OutOfMemory,
        AbortCode::UnsupportedAccess,
        AbortCode::WriteOnly,
        AbortCode::ReadOnly,
        AbortCode::NoObject,
        AbortCode::NotMappable,
        AbortCode::MappingTooLong,
        AbortCode::ParameterIncompatible,
        AbortCode::InternalIncompatible,
        AbortCode::HardwareError,
        AbortCode::LengthMismatch,
        AbortCode::LengthTooHigh,
        AbortCode::LengthTooLow,
        AbortCode::NoSubIndex,
        AbortCode::InvalidValue,
        AbortCode::ValueTooHigh,
        AbortCode::ValueTooLow,
        AbortCode::General,
        AbortCode::CannotStore,
        AbortCode::LocalControl,
        AbortCode::DeviceState,
    ];

    /// The 32-bit code as sent on the bus.
    pub const fn code(self) -> u32 {
        self as u32
    }

    /// What the code means, in the words of CiA 301 7.2.4.3.17 (the variant's doc comment), for
    /// tools that print an abort as a sentence.
    pub const fn meaning(self) -> &'static str {
        match self {
            AbortCode::ToggleBit => "Toggle bit not alternated.",
            AbortCode::Timeout => "SDO protocol timed out.",
            AbortCode::InvalidCommand => "Client/server command specifier not valid or unknown.",
            AbortCode::OutOfMemory => "Out of memory.",
            AbortCode::UnsupportedAccess => "Unsupported access to an object.",
            AbortCode::WriteOnly => "Attempt to read a write only object.",
            AbortCode::ReadOnly => "Attempt to write a read only object.",
            AbortCode::NoObject => "Object does not exist in the object dictionary.",
            AbortCode::NotMappable => {
                "Object cannot be mapped to the PDO (here: to the SRDO in this direction)."
            }
            AbortCode::MappingTooLong => {
                "The number and length of the objects to be mapped would exceed the PDO (SRDO) length."
            }
            AbortCode::ParameterIncompatible => "General parameter incompatibility reason.",
            AbortCode::InternalIncompatible => "General internal incompatibility in the device.",
            AbortCode::HardwareError => "Access failed due to a hardware error.",
            AbortCode::LengthMismatch => {
                "Data type does not match, length of service parameter does not match."
            }
            AbortCode::LengthTooHigh => {
                "Data type does not match, length of service parameter too high."
            }
            AbortCode::LengthTooLow => {
                "Data type does not match, length of service parameter too low."
            }
            AbortCode::NoSubIndex => "Sub-index does not exist.",
            AbortCode::InvalidValue => "Invalid value for parameter (download only).",
            AbortCode::ValueTooHigh => "Value of parameter written too high (download only).",
            AbortCode::ValueTooLow => "Value of parameter written too low (download only).",
            AbortCode::General => "General error.",
            AbortCode::CannotStore => "Data cannot be transferred or stored to the application.",
            AbortCode::LocalControl => {
                "Data cannot be transferred or stored to the application because of local control."
            }
            AbortCode::DeviceState => {
                "Data cannot be transferred or stored to the application because of the present device state."
            }
        }
    }

    /// The abort code with the value `code`, if this crate knows it.
    pub fn from_code(code: u32) -> Option<AbortCode> {
        AbortCode::ALL
            .iter()
            .copied()
            .find(|abort| abort.code() == code)
    }
}

/// Object access as the SDO server needs it.
///
/// Implementations apply the access rules (NMT state, value ranges, consistency) and answer
/// with the specific [`AbortCode`] when an access is refused. A refused write changes nothing.
pub trait ObjectDictionary {
    /// Reads the value of `address` into `buf` and returns its length in bytes.
    ///
    /// Values are little-endian, as on the bus. When `buf` is too small for the value the
    /// implementation answers [`AbortCode::OutOfMemory`].
    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode>;

    /// Writes `data` (little-endian, exactly as received) to `address`, all or nothing.
    fn write(&mut self, address: Address, data: &[u8]) -> Result<(), AbortCode>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn abort_codes_round_trip_and_are_distinct() {
        for abort in AbortCode::ALL {
            assert_eq!(AbortCode::from_code(abort.code()), Some(abort));
        }
        assert_eq!(AbortCode::from_code(0x1234_5678), None);
        assert_eq!(AbortCode::DeviceState.code(), 0x0800_0022);
    }

    #[test]
    fn cia301_7_2_4_3_17_abort_code_meanings_are_sentences() {
        for abort in AbortCode::ALL {
            let meaning = abort.meaning();
            assert!(!meaning.is_empty() && meaning.ends_with('.'), "{abort:?}");
        }
        assert_eq!(
            AbortCode::DeviceState.meaning(),
            "Data cannot be transferred or stored to the application because of the present \
             device state."
        );
    }
}
