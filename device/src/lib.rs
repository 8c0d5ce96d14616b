//! The device this node is: its application objects, their names and pins, and its
//! description for the protocol core. Both channels, the firmware images, the host
//! simulations, the tool and xtask use this one description.
//!
//! - the application objects ([`OBJECTS`]), their names ([`OBJECT_NAMES`]) and inverted
//!   pairs ([`INVERTED_PAIRS`]), and the pins they are sampled from or drive ([`INPUT_PINS`],
//!   [`OUTPUT_PINS`]);
//! - the SRDO count ([`SRDO_COUNT`]), the CAN bit rate ([`BIT_RATE`]), the channels' device
//!   names and the description for the protocol core ([`config`]);
//! - [`timing`]: the device's own timing (input sampling, the channels' sample window, the
//!   link between the channels), which the channels run with and the tool's response-time
//!   calculation adds up;
//! - [`switches`]: what the node-ID switches' readings at start-up mean;
//! - [`reset_cause`]: why a channel's MCU started, from its reset flags, in words;
//! - [`parameter_flash`]: where the device keeps its stored parameters (two slots in the
//!   STM32F405's flash sectors 10 and 11) and how the storage layer's records are written on
//!   that flash, in whole 32-bit words, over the board layer's flash driver
//!   ([`parameter_flash::Sectors`]).
//!
//! Only descriptions and the pure functions that read the device's own values: no runtime,
//! no I/O of its own, no heap. The board layers read the pins and registers and hand the
//! values here, and erase and program the flash for [`parameter_flash`].

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod parameter_flash;
pub mod reset_cause;
pub mod switches;
pub mod timing;

use shared::Duration;
use shared::canopen::NodeId;
use shared::canopen::od::Address;
use shared::node::NodeConfig;
use shared::process_image::{Access, AppObject, Mappable};

const fn object(index: u16, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, 1),
        len: 1,
        access: Access::ReadOnly,
        mappable,
    }
}

/// A safety input with its inverted copy (e.g. one contact of an emergency stop, 1 = closed,
/// released) and a safety output with its inverted copy (1 = the machine may run). 0 is the
/// safe state of both (SC_REQ_05).
pub static OBJECTS: [AppObject; 4] = [
    object(0x6000, Mappable::Transmit),
    object(0x6001, Mappable::Transmit),
    object(0x6200, Mappable::Receive),
    object(0x6201, Mappable::Receive),
];

/// Safety input (plain).
pub const INPUT: Address = Address::new(0x6000, 1);
/// Safety input (inverted copy).
pub const INPUT_INVERTED: Address = Address::new(0x6001, 1);
/// Safety output (plain).
pub const OUTPUT: Address = Address::new(0x6200, 1);
/// Safety output (inverted copy).
pub const OUTPUT_INVERTED: Address = Address::new(0x6201, 1);

/// The channel's input pins, in pin order: each sample is written to a plain safety object
/// and its inverted copy (pin 0: the channel's contact of the emergency stop, hardware PC0,
/// closed = 1).
pub static INPUT_PINS: [(Address, Address); 1] = [(INPUT, INPUT_INVERTED)];

/// The channel's output pins, in pin order, each with the received safety object that drives
/// it (pin 0: the channel's relay, hardware PC1, energised while 0x6200:1 is not 0). A pin
/// follows its object as both channels confirmed it: the cross-checked data of the receive
/// SRDO that maps it, or (SimpleCAN, SC_REQ_20) the cross-checked value of the consumed
/// SC-ID whose SDD entry maps it (5E10h.. :06); it is low whenever neither maps it, in the
/// safe state (SC_REQ_05) and before the first confirmed value.
pub static OUTPUT_PINS: [Address; 1] = [OUTPUT];

/// Each plain safety object with its inverted copy (EN 50325-5 6.4.1.3: an SRDO maps a
/// plain object on an odd sub-index and its inverted copy on the next; the EDS links them
/// with `InvertedSRAD`, CiA 306 Annex A).
pub static INVERTED_PAIRS: [(Address, Address); 2] =
    [(INPUT, INPUT_INVERTED), (OUTPUT, OUTPUT_INVERTED)];

/// How many SRDOs the node has (0x1301..=0x1304, 0x1381..=0x1384, 0x13FF sub-indices 1..=4);
/// both firmware images are built with it.
pub const SRDO_COUNT: usize = 4;

/// The CAN bit rate of the hardware (CiA 301 Table 1; the EDS's `BaudRate_500`).
pub const BIT_RATE: u32 = 500_000;

/// [`BIT_RATE`] as its entry of CiA 301's bit-timing table (CiA 305's index).
pub const BIT_RATE_ENTRY: shared::canopen::lss::BitRate = shared::canopen::lss::BitRate::Kbit500;

/// The bit rates LSS may configure on the hardware (CiA 305 configure bit timing, Fig. 34):
/// every rate of CiA 301's table that the CAN clock (APB1, 42 MHz) divides into exactly, with
/// the time quanta and sample point the board's bit-timing calculation gives, which the
/// hardware image checks for each of them at start-up (it halts in the safe state if one has
/// none). Not 800 kbit/s: 42 MHz divides into no whole number of quanta of it, so configure
/// bit timing to it is refused with error code 1 (CiA 305: bit timing not supported) and
/// changes nothing; nor automatic bit rate detection. Activate bit timing switches both
/// channels' controllers after the switch delay (the channel loop's `Driver::switch_bit_rate`).
pub const LSS_BIT_RATES: shared::canopen::lss::BitRates = {
    use shared::canopen::lss::BitRate;
    shared::canopen::lss::BitRates::of(&[
        BitRate::Kbit1000,
        BitRate::Kbit500,
        BitRate::Kbit250,
        BitRate::Kbit125,
        BitRate::Kbit50,
        BitRate::Kbit20,
        BitRate::Kbit10,
    ])
};

/// The bit rates LSS may configure on the hardware with SimpleCAN: those of
/// [`LSS_BIT_RATES`] at which a SimpleCAN packet fits its slot in the worst case, 500 kbit/s
/// and above (`docs/simplecan.md`, section 5).
pub const SIMPLECAN_LSS_BIT_RATES: shared::canopen::lss::BitRates = {
    use shared::canopen::lss::BitRate;
    shared::canopen::lss::BitRates::of(&[BitRate::Kbit1000, BitRate::Kbit500])
};

// The rate the hardware starts at is one LSS may configure.
const _: () = assert!(
    matches!(BIT_RATE_ENTRY.bits_per_second(), Some(BIT_RATE))
        && LSS_BIT_RATES.contains(BIT_RATE_ENTRY)
        && SIMPLECAN_LSS_BIT_RATES.contains(BIT_RATE_ENTRY),
    "BIT_RATE_ENTRY is not BIT_RATE, or LSS_BIT_RATES does not hold it"
);

/// The device name (0x1008) channel A's image reports; channel A answers SDO for the node.
pub const CHANNEL_A_NAME: &str = "safety node, channel A";
/// The device name (0x1008) channel B's image holds.
pub const CHANNEL_B_NAME: &str = "safety node, channel B";

/// The names a person uses for the application objects (in a network file, in a tool's
/// output), one per entry of [`OBJECTS`].
pub static OBJECT_NAMES: [(&str, Address); 4] = [
    ("input", INPUT),
    ("input_inverted", INPUT_INVERTED),
    ("output", OUTPUT),
    ("output_inverted", OUTPUT_INVERTED),
];

/// The device description for node-ID `id` (1..=127).
pub fn config(id: NodeId, name: &'static str) -> NodeConfig {
    NodeConfig {
        node_id: id,
        device_type: 0x0001_0191,
        device_name: name,
        identity: [0x0000_0ABC, 0x0000_0304, 1, u32::from(id.raw())],
        app_objects: &OBJECTS,
        default_transmit_mapping: &[0x6000_0108, 0x6001_0108],
        default_receive_mapping: &[0x6200_0108, 0x6201_0108],
        heartbeat_ms: 100,
        sdo_timeout: Duration::from_millis(500),
        event_driven: true,
        gfc_on_fault: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every application object has exactly one name, and every name an object.
    /// Every plain object of a pair is mappable in its copy's direction, with its length.
    #[test]
    fn inverted_pairs_name_objects_of_one_direction_and_length() {
        let find = |address: Address| OBJECTS.iter().find(|o| o.address == address);
        for (plain, inverted) in INVERTED_PAIRS {
            let (plain, inverted) = (find(plain).unwrap(), find(inverted).unwrap());
            assert_eq!(plain.mappable, inverted.mappable);
            assert_eq!(plain.len, inverted.len);
        }
        assert_eq!(INVERTED_PAIRS.len() * 2, OBJECTS.len());
    }

    #[test]
    fn every_object_has_one_name() {
        for object in &OBJECTS {
            let named = OBJECT_NAMES
                .iter()
                .filter(|(_, address)| *address == object.address)
                .count();
            assert_eq!(named, 1, "{:?}", object.address);
        }
        assert_eq!(OBJECT_NAMES.len(), OBJECTS.len());
    }
}
