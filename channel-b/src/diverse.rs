//! Channel B's own way of building a transmit SRDO (CiA 304 9.5: "each transmit SRDO built by
//! two different ways"), deliberately not a call into the protocol core.
//!
//! Where channel A (through `shared`) keeps inputs in a byte-packed process image, resolves the
//! mapping once into spans and assembles the frame as one `u64` inverted with `!`, channel B:
//!
//! - keeps its inputs as a list of `(index, sub-index, value)` records ([`InputTable`]),
//! - decodes each raw mapping entry (`0x1381+n` sub 1..16) itself, at every transmission,
//! - lays the frame out byte by byte from each value's little-endian bytes, and
//! - inverts by subtraction from 0xFF, byte by byte.
//!
//! [`build_plain`] gives B's plain half; [`compare_and_invert`] checks channel A's plain frame
//! on the bus against it, bit by bit, and only then gives the inverted frame to send.

/// One input as channel B holds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Input {
    /// Object index.
    pub index: u16,
    /// Object sub-index.
    pub sub: u8,
    /// Length in bytes, 1..=8.
    pub len: u8,
    /// Value, little-endian in the low `len` bytes.
    pub value: u64,
}

/// Channel B's inputs: a short list searched linearly (a different layout from A's image).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct InputTable {
    inputs: heapless::Vec<Input, 16>,
}

/// Why channel B could not build or confirm a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DiverseError {
    /// A mapping entry names an object channel B does not have.
    UnknownObject,
    /// A mapping entry's length is not the object's length, or not whole bytes.
    LengthMismatch,
    /// The plain objects add up to more than 8 bytes.
    TooLong,
    /// The input table is full.
    TableFull,
    /// Channel A's plain frame on the bus differs from channel B's own result.
    Mismatch,
}

impl InputTable {
    /// An empty table.
    pub const fn new() -> Self {
        InputTable {
            inputs: heapless::Vec::new(),
        }
    }

    /// Declares an input of `len` bytes (value 0, the safe state).
    pub fn declare(&mut self, index: u16, sub: u8, len: u8) -> Result<(), DiverseError> {
        if !(1..=8).contains(&len) {
            return Err(DiverseError::LengthMismatch);
        }
        self.inputs
            .push(Input {
                index,
                sub,
                len,
                value: 0,
            })
            .map_err(|_| DiverseError::TableFull)
    }

    /// Sets an input's value (bytes beyond its length are ignored).
    pub fn set(&mut self, index: u16, sub: u8, value: u64) -> Result<(), DiverseError> {
        let input = self
            .inputs
            .iter_mut()
            .find(|input| input.index == index && input.sub == sub)
            .ok_or(DiverseError::UnknownObject)?;
        input.value = value;
        Ok(())
    }

    fn lookup(&self, index: u16, sub: u8) -> Option<&Input> {
        self.inputs
            .iter()
            .find(|input| input.index == index && input.sub == sub)
    }
}

/// Channel B's plain half of a transmit SRDO: the plain (odd) mapping entries of `mapping`
/// (raw `0x1381+n` sub 1..) laid out from B's own inputs. Returns the bytes and the length.
pub fn build_plain(mapping: &[u32], inputs: &InputTable) -> Result<([u8; 8], usize), DiverseError> {
    let mut frame = [0u8; 8];
    let mut length = 0usize;
    // Odd sub-indices (1, 3, 5, ...) are the plain objects: positions 0, 2, 4, ... here.
    for entry in mapping.iter().step_by(2) {
        let index = (entry >> 16) as u16;
        let sub = (entry >> 8) as u8;
        let bits = (entry & 0xFF) as u8;
        let input = inputs
            .lookup(index, sub)
            .ok_or(DiverseError::UnknownObject)?;
        if bits % 8 != 0 || bits / 8 != input.len {
            return Err(DiverseError::LengthMismatch);
        }
        let bytes = usize::from(input.len);
        if length + bytes > 8 {
            return Err(DiverseError::TooLong);
        }
        let mut value = input.value;
        for slot in &mut frame[length..length + bytes] {
            *slot = (value & 0xFF) as u8;
            value >>= 8;
        }
        length += bytes;
    }
    Ok((frame, length))
}

/// Inverts `len` bytes by subtraction from 0xFF (channel A uses a bitwise NOT on a `u64`).
pub fn invert(frame: &[u8; 8], len: usize) -> [u8; 8] {
    let mut inverted = [0u8; 8];
    for (out, byte) in inverted.iter_mut().zip(frame).take(len) {
        *out = 0xFF - byte;
    }
    inverted
}

/// Channel A's plain frame as seen on the bus, against channel B's own plain half: equal in
/// length and in every bit, or [`DiverseError::Mismatch`]. When equal, the inverted frame B
/// sends (CiA 304 9.5).
pub fn compare_and_invert(
    observed: &[u8],
    mapping: &[u32],
    inputs: &InputTable,
) -> Result<[u8; 8], DiverseError> {
    let (own, len) = build_plain(mapping, inputs)?;
    // Bit by bit: XOR of every byte pair must be zero, and the lengths must agree.
    let mut difference = u8::from(observed.len() != len);
    for (a, b) in observed.iter().zip(&own[..len]) {
        difference |= a ^ b;
    }
    if difference != 0 {
        return Err(DiverseError::Mismatch);
    }
    Ok(invert(&own, len))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use proptest::strategy::ValueTree;
    use shared::canopen::od::Address;
    use shared::process_image::{Access, AppObject, Mappable, ProcessImage};
    use shared::safety::config::{SrdoRecord, check_mapping};
    use shared::safety::srdo::gather;
    use shared::safety::types::Direction;

    /// Plain objects of 1, 2, 4 and 8 bytes and their inverted copies (index + 0x100).
    const fn object(index: u16, sub: u8, len: u8) -> AppObject {
        AppObject {
            address: Address::new(index, sub),
            len,
            access: Access::ReadOnly,
            mappable: Mappable::Transmit,
        }
    }
    static OBJECTS: [AppObject; 16] = [
        object(0x6000, 1, 1),
        object(0x6000, 2, 1),
        object(0x6000, 3, 1),
        object(0x6000, 4, 1),
        object(0x6010, 1, 2),
        object(0x6010, 2, 2),
        object(0x6020, 1, 4),
        object(0x6030, 1, 8),
        object(0x6100, 1, 1),
        object(0x6100, 2, 1),
        object(0x6100, 3, 1),
        object(0x6100, 4, 1),
        object(0x6110, 1, 2),
        object(0x6110, 2, 2),
        object(0x6120, 1, 4),
        object(0x6130, 1, 8),
    ];
    /// The plain objects (the first eight).
    const PLAIN: usize = 8;

    fn entry(object: &AppObject) -> u32 {
        (u32::from(object.address.index) << 16)
            | (u32::from(object.address.sub) << 8)
            | (u32::from(object.len) * 8)
    }

    /// Every ordered selection of distinct plain objects with at most 8 bytes in all.
    fn layouts() -> Vec<Vec<usize>> {
        fn extend(prefix: Vec<usize>, bytes: u8, out: &mut Vec<Vec<usize>>) {
            if !prefix.is_empty() {
                out.push(prefix.clone());
            }
            for (next, object) in OBJECTS[..PLAIN].iter().enumerate() {
                let len = object.len;
                if !prefix.contains(&next) && bytes + len <= 8 {
                    let mut longer = prefix.clone();
                    longer.push(next);
                    extend(longer, bytes + len, out);
                }
            }
        }
        let mut out = Vec::new();
        extend(Vec::new(), 0, &mut out);
        out
    }

    /// CiA 304 9.5: channel B's own path builds the same plain and inverted frames as channel
    /// A's (the protocol core's) for every mappable layout of the test device, with random
    /// values.
    #[test]
    fn cia304_9_5_b_builds_what_a_builds_for_every_layout() {
        let layouts = layouts();
        assert!(layouts.len() > 1000, "{} layouts", layouts.len());
        let mut runner = proptest::test_runner::TestRunner::deterministic();
        for layout in &layouts {
            let mut mapping = Vec::new();
            for &plain in layout {
                mapping.push(entry(&OBJECTS[plain]));
                mapping.push(entry(&OBJECTS[plain + PLAIN]));
            }
            let mut record = SrdoRecord::DELETED;
            record.mapping_count = mapping.len() as u8;
            record.mapping[..mapping.len()].copy_from_slice(&mapping);
            let mut image = ProcessImage::new(&OBJECTS).unwrap();
            let resolved = check_mapping(&record, &image, Some(Direction::Transmit)).unwrap();
            let values: Vec<u64> = (0..PLAIN)
                .map(|_| any::<u64>().new_tree(&mut runner).unwrap().current())
                .collect();
            let mut inputs = InputTable::new();
            for (i, object) in OBJECTS[..PLAIN].iter().enumerate() {
                let (index, sub) = (object.address.index, object.address.sub);
                inputs.declare(index, sub, object.len).unwrap();
                inputs.set(index, sub, values[i]).unwrap();
                let len = usize::from(object.len);
                let bytes = values[i].to_le_bytes();
                let (_, span) = image.find(object.address).unwrap();
                image.set(span, &bytes[..len]);
                let inverted: Vec<u8> = bytes[..len].iter().map(|b| !b).collect();
                let (_, span) = image.find(OBJECTS[i + PLAIN].address).unwrap();
                image.set(span, &inverted);
            }
            let (a_plain, a_inverted) = gather(&image, &resolved).unwrap();
            let (b_plain, len) = build_plain(&mapping, &inputs).unwrap();
            assert_eq!(len, usize::from(resolved.len), "{layout:?}");
            assert_eq!(&b_plain[..len], &a_plain.to_le_bytes()[..len], "{layout:?}");
            assert_eq!(
                &invert(&b_plain, len)[..len],
                &a_inverted.to_le_bytes()[..len]
            );
            assert_eq!(
                compare_and_invert(&a_plain.to_le_bytes()[..len], &mapping, &inputs),
                Ok(invert(&b_plain, len))
            );
        }
    }

    proptest! {
        /// CiA 304 9.5: any single-bit difference between A's frame and B's inputs
        /// means B sends nothing.
        #[test]
        fn any_bit_difference_is_a_mismatch(value in any::<u32>(), bit in 0u32..32) {
            let mut inputs = InputTable::new();
            inputs.declare(0x6020, 1, 4).unwrap();
            inputs.set(0x6020, 1, u64::from(value)).unwrap();
            let mapping = [0x6020_0120, 0x6120_0120];
            let observed = (value ^ (1 << bit)).to_le_bytes();
            prop_assert_eq!(
                compare_and_invert(&observed, &mapping, &inputs),
                Err(DiverseError::Mismatch)
            );
            prop_assert!(compare_and_invert(&value.to_le_bytes(), &mapping, &inputs).is_ok());
            // A frame of another length never matches.
            prop_assert_eq!(
                compare_and_invert(&value.to_le_bytes()[..3], &mapping, &inputs),
                Err(DiverseError::Mismatch)
            );
        }
    }

    #[test]
    fn mappings_b_cannot_build_are_refused() {
        let mut inputs = InputTable::new();
        inputs.declare(0x6000, 1, 1).unwrap();
        assert_eq!(
            build_plain(&[0x6001_0108, 0], &inputs),
            Err(DiverseError::UnknownObject)
        );
        assert_eq!(
            build_plain(&[0x6000_0110, 0], &inputs),
            Err(DiverseError::LengthMismatch)
        );
        assert_eq!(
            inputs.declare(0x6002, 1, 9),
            Err(DiverseError::LengthMismatch)
        );
        let mut wide = InputTable::new();
        wide.declare(0x6030, 1, 8).unwrap();
        wide.declare(0x6000, 1, 1).unwrap();
        assert_eq!(
            build_plain(&[0x6030_0140, 0, 0x6000_0108, 0], &wide),
            Err(DiverseError::TooLong)
        );
    }
}
