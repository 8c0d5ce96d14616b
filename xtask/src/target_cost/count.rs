//! What is left of the QEMU instruction trace's reader, for `xtask/src/qemu.rs` only until the
//! QEMU images retire (with `xtask/src/qemu.rs`, this module goes).

/// The program counter of one `-d exec` line with one instruction per translation block,
/// `Trace 0: 0x… [flags/pc/…] symbol`, and whether the instruction ran in handler mode (bit 0
/// of the block's flags is QEMU's handler-mode flag for M-profile cores).
pub fn exec_pc(line: &[u8]) -> Option<(u32, bool)> {
    let rest = line.strip_prefix(b"Trace ")?;
    let open = rest.iter().position(|&b| b == b'[')?;
    let mut fields = rest[open + 1..].split(|&b| b == b'/');
    let flags = hex(fields.next()?)?;
    let pc = hex(fields.next()?)?;
    Some((pc as u32, flags & 1 == 1))
}

/// A hexadecimal number of 1 to 16 digits.
fn hex(digits: &[u8]) -> Option<u64> {
    if digits.is_empty() || digits.len() > 16 {
        return None;
    }
    digits.iter().try_fold(0u64, |value, &digit| {
        Some(value << 4 | u64::from(char::from(digit).to_digit(16)?))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trace line gives its program counter and its handler-mode flag; other lines none.
    #[test]
    fn an_exec_line_gives_its_address_and_mode() {
        assert_eq!(
            exec_pc(b"Trace 0: 0x7f00 [00000101/08000234/00000000/ff200000] main"),
            Some((0x0800_0234, true))
        );
        assert_eq!(
            exec_pc(b"Trace 0: 0x7f00 [00000100/08000236/00000000/ff200000] main"),
            Some((0x0800_0236, false))
        );
        assert_eq!(exec_pc(b"IN: main"), None);
    }
}
