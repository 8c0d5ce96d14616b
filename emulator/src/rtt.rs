//! The defmt log's way out of the image: the SEGGER RTT control block `defmt-rtt` keeps in
//! RAM (`_SEGGER_RTT`), whose up-buffer 0 the emulator drains as a debug probe would.
//!
//! Layout (SEGGER RTT, as `defmt-rtt` 1 declares it): the identifier "SEGGER RTT" in 16
//! bytes, the number of up and down buffers, then each up buffer: name pointer, buffer
//! pointer, size, write offset, read offset, flags (six 32-bit words).

/// What the drain needs of the emulated memory.
pub trait Memory {
    /// Reads `buf.len()` bytes at `address`; `false` when the range is not RAM.
    fn read(&mut self, address: u32, buf: &mut [u8]) -> bool;
    /// Writes `bytes` at `address`; `false` when the range is not RAM.
    fn write(&mut self, address: u32, bytes: &[u8]) -> bool;
}

/// The control block's identifier.
const ID: &[u8; 10] = b"SEGGER RTT";
/// Offset of up buffer 0 in the control block.
const UP0: u32 = 24;

/// The largest up buffer the drain accepts (a corrupt size is not followed).
const MAX_BUFFER: u32 = 64 * 1024;

/// Takes what the image has written into up buffer 0 since the last drain, and moves its
/// read offset on. Returns nothing while the control block is not initialised (before
/// `.data` is copied, or if the image does not log over RTT).
pub fn drain(memory: &mut impl Memory, control_block: u32) -> Vec<u8> {
    let mut header = [0u8; 16];
    if !memory.read(control_block, &mut header) || &header[..ID.len()] != ID {
        return Vec::new();
    }
    let mut words = [0u8; 24];
    if !memory.read(control_block + UP0, &mut words) {
        return Vec::new();
    }
    let word = |i: usize| {
        u32::from_le_bytes([
            words[4 * i],
            words[4 * i + 1],
            words[4 * i + 2],
            words[4 * i + 3],
        ])
    };
    let (buffer, size, write, read) = (word(1), word(2), word(3), word(4));
    if size == 0 || size > MAX_BUFFER || write >= size || read >= size || write == read {
        return Vec::new();
    }
    let mut out = Vec::new();
    let mut take = |from: u32, to: u32| {
        let mut chunk = vec![0u8; (to - from) as usize];
        if memory.read(buffer + from, &mut chunk) {
            out.extend_from_slice(&chunk);
        }
    };
    if write > read {
        take(read, write);
    } else {
        take(read, size);
        take(0, write);
    }
    // The read offset, at word 4 of the up buffer.
    memory.write(control_block + UP0 + 16, &write.to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Ram(Vec<u8>);

    impl Memory for Ram {
        fn read(&mut self, address: u32, buf: &mut [u8]) -> bool {
            let at = address as usize;
            match self.0.get(at..at + buf.len()) {
                Some(bytes) => {
                    buf.copy_from_slice(bytes);
                    true
                }
                None => false,
            }
        }
        fn write(&mut self, address: u32, bytes: &[u8]) -> bool {
            let at = address as usize;
            match self.0.get_mut(at..at + bytes.len()) {
                Some(to) => {
                    to.copy_from_slice(bytes);
                    true
                }
                None => false,
            }
        }
    }

    fn control_block(ram: &mut Ram, write: u32, read: u32) {
        ram.0[..10].copy_from_slice(ID);
        let words = [0u32, 100, 8, write, read, 0];
        for (i, w) in words.iter().enumerate() {
            ram.0[24 + 4 * i..28 + 4 * i].copy_from_slice(&w.to_le_bytes());
        }
        ram.0[100..108].copy_from_slice(b"abcdefgh");
    }

    #[test]
    fn segger_rtt_up_buffer_is_drained_across_its_wrap_and_its_read_offset_moves() {
        let mut ram = Ram(vec![0; 128]);
        control_block(&mut ram, 2, 6);
        assert_eq!(drain(&mut ram, 0), b"ghab");
        assert_eq!(ram.0[40..44], 2u32.to_le_bytes());
        assert!(drain(&mut ram, 0).is_empty());
    }

    #[test]
    fn segger_rtt_nothing_is_read_before_the_control_block_is_initialised() {
        let mut ram = Ram(vec![0; 128]);
        assert!(drain(&mut ram, 0).is_empty());
    }
}
