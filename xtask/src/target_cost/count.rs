//! The counting half of `cargo xtask bench --target-cost`: calls of tracked functions in a
//! QEMU instruction trace (`-d exec,nochain` with `one-insn-per-tb`: one line per executed
//! instruction), each with its instructions and the tracked calls made inside it.

use anyhow::{Context, Result};
use std::io::BufRead as _;
use std::path::Path;

/// A call longer than this is taken for one whose return was not recognised, and dropped.
const ABANDON_AFTER: u64 = 2_000_000;

/// One complete call of a tracked function.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Call {
    /// Which of the tracked entries.
    pub function: usize,
    /// Thread-mode instructions from the entry to the return, callees included.
    pub instructions: u64,
    /// The tracked calls made inside it, in the order they returned: (function, their
    /// instructions). Only for the functions asked for ([`count_calls`]'s `nesting`).
    pub nested: Vec<(usize, u64)>,
    /// Its instructions by the symbol QEMU names for each (the function of the image that
    /// holds the address, so code inlined into a function counts as that function's), the
    /// most first; a memory routine's ([`is_memory_routine`]) as `routine <- caller`, the
    /// function it was last entered from. Only for the functions asked for, as `nested`.
    pub symbols: Vec<(String, u64)>,
}

impl Call {
    /// A call of `function` of `instructions` with the tracked calls `nested` inside it and
    /// no symbols: what the tests of the counts build their traces from.
    #[cfg(test)]
    pub fn traced(function: usize, instructions: u64, nested: Vec<(usize, u64)>) -> Call {
        Call {
            function,
            instructions,
            nested,
            symbols: Vec::new(),
        }
    }

    /// Whether a call of `function` was made inside this one.
    pub fn made(&self, function: usize) -> bool {
        self.nested.iter().any(|(f, _)| *f == function)
    }

    /// Its instructions without those of the calls of `subtracted` made inside it (not
    /// nested in one another: the markers).
    pub fn without(&self, subtracted: &[usize]) -> u64 {
        let inside: u64 = self
            .nested
            .iter()
            .filter(|(f, _)| subtracted.contains(f))
            .map(|(_, count)| count)
            .sum();
        self.instructions - inside
    }
}

/// What a trace holds: every complete call of a tracked function in the order they
/// returned, and how many lines it has.
#[derive(Debug, Default)]
pub struct Counted {
    pub calls: Vec<Call>,
    pub lines: u64,
}

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

/// The symbol at the end of a `-d exec` line (after the closing bracket), without the line
/// end; empty when QEMU names none.
pub fn exec_symbol(line: &[u8]) -> &[u8] {
    let after = line
        .iter()
        .rposition(|&b| b == b']')
        .map_or(&line[line.len()..], |at| &line[at + 1..]);
    after.trim_ascii()
}

/// What [`Call::symbols`] puts between a memory routine and the function that called it.
pub const CALLED_FROM: &str = " <- ";

/// `memcpy`, `memset`, `memclr`, `memmove`, `memcmp` in any of their names (the AEABI
/// entries, compiler-builtins' and libc's): shared by every caller, so the breakdown names
/// who called them.
pub fn is_memory_routine(symbol: &[u8]) -> bool {
    [&b"memcpy"[..], b"memset", b"memclr", b"memmove", b"memcmp"]
        .iter()
        .any(|name| symbol.windows(name.len()).any(|window| window == *name))
}

/// A hexadecimal field (at most 16 digits).
fn hex(digits: &[u8]) -> Option<u64> {
    if digits.is_empty() || digits.len() > 16 {
        return None;
    }
    digits.iter().try_fold(0u64, |value, &digit| {
        Some(value << 4 | u64::from(char::from(digit).to_digit(16)?))
    })
}

/// The calls of the functions at `entries` in `trace`. A call starts at a line at the entry
/// address reached from a `bl` (4 bytes before the address it returns to) and ends at the
/// first line at the return address; the lines between are its instructions, counted in
/// thread mode only: an interrupt handler that runs meanwhile (QEMU flags its blocks as
/// handler mode) is not the call's cost. Calls of the functions in `nesting` keep the list of
/// the tracked calls made inside them.
pub fn count_calls(trace: &Path, entries: &[u32], nesting: &[usize]) -> Result<Counted> {
    let file = std::fs::File::open(trace)
        .with_context(|| format!("reading the trace {}", trace.display()))?;
    let mut reader = std::io::BufReader::with_capacity(1 << 20, file);
    let mut counter = Counter::default();
    let mut line = Vec::with_capacity(256);
    loop {
        line.clear();
        if reader.read_until(b'\n', &mut line)? == 0 {
            break;
        }
        counter.line(&line, entries, nesting);
    }
    Ok(counter.done())
}

/// One call in progress.
struct Open {
    function: usize,
    /// The address it returns to.
    back: u32,
    instructions: u64,
    nested: Vec<(usize, u64)>,
    /// Instructions by symbol, for the functions in `nesting`.
    symbols: std::collections::HashMap<Vec<u8>, u64>,
}

/// The calls in progress and those done, line by line.
#[derive(Default)]
struct Counter {
    counted: Counted,
    open: Vec<Open>,
    previous: Option<u32>,
    /// The last symbol that was not a memory routine: who called the one running now.
    caller: Vec<u8>,
}

impl Counter {
    fn line(&mut self, line: &[u8], entries: &[u32], nesting: &[usize]) {
        self.counted.lines += 1;
        let Some((pc, handler)) = exec_pc(line) else {
            return;
        };
        if handler {
            return;
        }
        // Returns first: the instruction after the call is not part of it. A call returns
        // to its caller, so the innermost open calls close first.
        // Calls opened inside it that have not returned (entered otherwise than by `bl`) end
        // with it, uncounted: their instructions are its own.
        while let Some(index) = self.open.iter().rposition(|call| call.back == pc) {
            self.open.truncate(index + 1);
            let Some(call) = self.open.pop() else {
                break;
            };
            for outer in self.open.iter_mut() {
                if nesting.contains(&outer.function) {
                    outer.nested.push((call.function, call.instructions));
                }
            }
            let mut symbols: Vec<(String, u64)> = call
                .symbols
                .into_iter()
                .map(|(name, count)| (String::from_utf8_lossy(&name).into_owned(), count))
                .collect();
            symbols.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
            self.counted.calls.push(Call {
                function: call.function,
                instructions: call.instructions,
                nested: call.nested,
                symbols,
            });
        }
        let mut symbol = exec_symbol(line).to_vec();
        if is_memory_routine(&symbol) {
            symbol.extend_from_slice(CALLED_FROM.as_bytes());
            symbol.extend_from_slice(&self.caller);
        } else {
            self.caller.clone_from(&symbol);
        }
        let symbol = &symbol[..];
        for call in self.open.iter_mut() {
            call.instructions += 1;
            if nesting.contains(&call.function) {
                match call.symbols.get_mut(symbol) {
                    Some(count) => *count += 1,
                    None => {
                        call.symbols.insert(symbol.to_vec(), 1);
                    }
                }
            }
        }
        // One entered otherwise than by `bl` (a tail call) never sees its return address.
        self.open.retain(|call| call.instructions < ABANDON_AFTER);
        if let (Some(function), Some(from)) =
            (entries.iter().position(|&at| at == pc), self.previous)
        {
            let mut symbols = std::collections::HashMap::new();
            if nesting.contains(&function) {
                symbols.insert(exec_symbol(line).to_vec(), 1);
            }
            self.open.push(Open {
                function,
                back: from + 4,
                instructions: 1,
                nested: Vec::new(),
                symbols,
            });
        }
        self.previous = Some(pc);
    }

    fn done(self) -> Counted {
        self.counted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(pc: u32) -> String {
        // The symbol QEMU would name: the "function" of the address's 256-byte page.
        format!(
            "Trace 0: 0x7f00 [00800408/{pc:016x}/00000110/ff020201] f{:x}",
            pc >> 8
        )
    }

    fn handler(pc: u32) -> String {
        format!("Trace 0: 0x7f00 [00800409/{pc:016x}/00000110/ff020201] h")
    }

    fn count(text: &[String], entries: &[u32], nesting: &[usize]) -> Counted {
        let mut counter = Counter::default();
        for line in text {
            counter.line(line.as_bytes(), entries, nesting);
        }
        counter.done()
    }

    /// A call is counted from its entry to the return to the instruction after its `bl`,
    /// nested calls included, interrupt handlers not; a call still open at the end of the
    /// trace is not counted.
    #[test]
    fn calls_are_counted_from_entry_to_return() {
        let mut text = vec!["IN: noise".to_owned()];
        // bl at 0x100 → 0x200, bl at 0x202 → 0x300 (one instruction) → back at 0x206, an
        // interrupt handler of two that is not counted, back at 0x104: 4 instructions.
        text.extend([line(0x100), line(0x200), line(0x202)]);
        text.extend([handler(0x500), handler(0x502)]);
        text.extend([line(0x300), line(0x206), line(0x104), line(0x106)]);
        // A second call, cut off by the end of the trace.
        text.extend([line(0x110), line(0x200)]);
        let counted = count(&text, &[0x200, 0x300, 0x900], &[0]);
        assert_eq!(
            counted.calls,
            vec![
                Call {
                    function: 1,
                    instructions: 1,
                    nested: vec![],
                    symbols: vec![],
                },
                Call {
                    function: 0,
                    instructions: 4,
                    nested: vec![(1, 1)],
                    symbols: vec![("f2".to_owned(), 3), ("f3".to_owned(), 1)],
                },
            ]
        );
        assert_eq!(counted.lines, 12);
        assert_eq!(counted.calls[1].without(&[1]), 3);
    }

    /// A memory routine's instructions are named with the function it was entered from, so
    /// that clears and copies shared by every caller can be told apart.
    #[test]
    fn a_memory_routine_is_named_with_its_caller() {
        let named = |pc: u32, symbol: &str| {
            format!("Trace 0: 0x7f00 [00800408/{pc:016x}/00000110/ff020201] {symbol}")
        };
        // f calls g (bl at 0x102); g calls __aeabi_memclr4 twice (two instructions, then
        // one), f calls it once (one instruction); g returns to 0x106.
        let text = [
            named(0x100, "f"),
            named(0x102, "f"),
            named(0x200, "g"),
            named(0x900, "__aeabi_memclr4"),
            named(0x902, "__aeabi_memclr4"),
            named(0x204, "g"),
            named(0x900, "__aeabi_memclr4"),
            named(0x208, "g"),
            named(0x106, "f"),
            named(0x900, "__aeabi_memclr4"),
            named(0x108, "f"),
        ];
        let counted = count(&text, &[0x200], &[0]);
        assert_eq!(
            counted.calls[0].symbols,
            vec![("__aeabi_memclr4 <- g".to_owned(), 3), ("g".to_owned(), 3),]
        );
        assert!(is_memory_routine(
            b"_ZN17compiler_builtins3mem6memcpy17h0123456789abcdefE"
        ));
        assert!(!is_memory_routine(b"dual_channel::channel_loop::hand"));
    }
}
