//! Channel B's part in the pair (CiA 304 9.5, EN 50325-5 Annex A.4): silent on the bus except
//! for the inverted frame of each transmit SRDO, which it builds by its own path
//! ([`crate::diverse`]) and sends only after channel A's plain frame matched its own result bit
//! by bit. It follows SDO requests into its own copy of the object dictionary (the core does
//! that), and signs the configuration with its own CRC ([`crate::signature`]).

use crate::diverse::{DiverseError, InputTable, compare_and_invert};
use crate::signature::{Parameters, signature};
use dual_channel::runtime::{Role, fold_signatures};
use shared::canopen::od::Address;
use shared::safety::config::SafetyConfig;
use shared::{CanFrame, CanId};

/// Channel B's role: its own inputs, in its own layout.
#[derive(Clone, Debug, Default)]
pub struct ChannelB {
    inputs: InputTable,
}

impl ChannelB {
    /// Channel B with the inputs it samples (index, sub-index, length in bytes).
    pub fn new(inputs: &[(u16, u8, u8)]) -> Result<Self, DiverseError> {
        let mut table = InputTable::new();
        for &(index, sub, len) in inputs {
            table.declare(index, sub, len)?;
        }
        Ok(ChannelB { inputs: table })
    }
}

impl<const N: usize> Role<N> for ChannelB {
    fn outgoing(&mut self, _frame: CanFrame, _config: &SafetyConfig<N>) -> Option<CanFrame> {
        None
    }

    fn observe(
        &mut self,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, u8> {
        if frame.is_remote() {
            return Ok(None);
        }
        let id = u32::from(frame.id().raw());
        // Channel B's own reading of the raw records: direction 1, plain COB-ID matching.
        let Some((position, record)) = config
            .srdos
            .iter()
            .enumerate()
            .find(|(_, record)| record.direction == 1 && record.cob_id_1 & 0x7FF == id)
        else {
            return Ok(None);
        };
        let srdo = (position + 1) as u8;
        let mapping = &record.mapping[..usize::from(record.mapping_count).min(16)];
        let inverted = compare_and_invert(frame.data(), mapping, &self.inputs).map_err(|_| srdo)?;
        let id = CanId::new((record.cob_id_2 & 0x7FF) as u16).map_err(|_| srdo)?;
        let len = frame.data().len();
        CanFrame::new(id, &inverted[..len])
            .map(Some)
            .map_err(|_| srdo)
    }

    fn input(&mut self, address: Address, value: &[u8]) {
        let mut bytes = [0u8; 8];
        let len = value.len().min(8);
        bytes[..len].copy_from_slice(&value[..len]);
        // An input B does not sample is not B's: its transmit check then fails, as it must.
        let _ = self
            .inputs
            .set(address.index, address.sub, u64::from_le_bytes(bytes));
    }

    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32 {
        fold_signatures(config.srdos.iter().map(|record| {
            signature(&Parameters {
                direction: record.direction,
                cycle_time: record.cycle_time,
                srvt: record.srvt,
                cob_id_1: record.cob_id_1,
                cob_id_2: record.cob_id_2,
                mapping: &record.mapping[..usize::from(record.mapping_count).min(16)],
            })
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> SafetyConfig<1> {
        SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[])
    }

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    /// CiA 304 9.5: B answers A's plain frame with the inverted frame when its own input
    /// agrees, and with nothing (and the SRDO number) when it does not.
    #[test]
    fn cia304_9_5_b_sends_the_inverted_frame_only_after_a_bit_exact_match() {
        let mut b = ChannelB::new(&[(0x6000, 1, 1)]).unwrap();
        Role::<1>::input(&mut b, Address::new(0x6000, 1), &[0x01]);
        assert_eq!(
            b.observe(&frame(0x101, &[0x01]), &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        assert_eq!(b.observe(&frame(0x101, &[0x00]), &config()), Err(1));
        // Not a transmit SRDO's plain frame: nothing to do.
        assert_eq!(b.observe(&frame(0x102, &[0xFE]), &config()), Ok(None));
        assert_eq!(b.observe(&frame(0x701, &[0x05]), &config()), Ok(None));
        // B never sends what its core produces.
        assert_eq!(b.outgoing(frame(0x581, &[0; 8]), &config()), None);
    }

    /// Both channels fold the same signatures, each computed its own way.
    #[test]
    fn the_digests_of_both_channels_agree() {
        let b = ChannelB::default();
        let config = config();
        assert_eq!(
            Role::<1>::signature_digest(&b, &config),
            fold_signatures(config.srdos.iter().map(shared::safety::signature::compute))
        );
    }
}
