//! Channel A's part in the pair (CiA 304 9.5, EN 50325-5 Annex A.4): it speaks for the node on
//! the bus (SDO answers, NMT boot-up and heartbeat, EMCY, GFC) and sends the plain frame of
//! every transmit SRDO, built by the protocol core. The inverted frame is channel B's.

use dual_channel::runtime::{Role, fold_signatures};
use shared::CanFrame;
use shared::canopen::od::Address;
use shared::safety::config::SafetyConfig;
use shared::safety::signature;
use shared::safety::types::Direction;

/// Channel A's role.
#[derive(Clone, Copy, Debug, Default)]
pub struct ChannelA;

impl<const N: usize> Role<N> for ChannelA {
    fn outgoing(&mut self, frame: CanFrame, config: &SafetyConfig<N>) -> Option<CanFrame> {
        let id = u32::from(frame.id().raw());
        let inverted_of_transmit = config.srdos.iter().any(|record| {
            record.parsed_direction() == Ok(Direction::Transmit) && record.cob_id_2 & 0x7FF == id
        });
        (!inverted_of_transmit).then_some(frame)
    }

    fn observe(
        &mut self,
        _frame: &CanFrame,
        _config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, u8> {
        Ok(None)
    }

    fn input(&mut self, _address: Address, _value: &[u8]) {
        // Channel A's inputs live in its core's process image, written by the runtime.
    }

    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32 {
        // Table-driven CRC-16 of the `crc` crate, through the protocol core.
        fold_signatures(config.srdos.iter().map(signature::compute))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    fn frame(id: u16) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &[1]).unwrap()
    }

    /// Channel A sends the plain frame and everything else, never the inverted frame of a
    /// transmit SRDO.
    #[test]
    fn cia304_9_5_a_sends_the_plain_frame_only() {
        let config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut a = ChannelA;
        assert!(a.outgoing(frame(0x101), &config).is_some());
        assert!(a.outgoing(frame(0x102), &config).is_none());
        assert!(a.outgoing(frame(0x701), &config).is_some());
        assert!(a.outgoing(frame(0x581), &config).is_some());
        // A receive SRDO's identifiers are not A's to filter (it never sends them anyway).
        let consumer = SafetyConfig::<2>::predefined(33, &[], &[0x6200_0108, 0x6201_0108]);
        assert!(a.outgoing(frame(0x142), &consumer).is_some());
    }
}
