//! The arguments of an emulated run, as `cargo xtask` gives them on QEMU's semihosting
//! command line (`node=N`, `paced`, `selftest`, `crash`). The QEMU board layer reads the
//! line; what its words mean is here, host-tested.

use shared::canopen::NodeId;

/// The arguments of an emulated run (QEMU semihosting command line, words separated by
/// spaces): `selftest` stops after the start-up self-tests; `node=N` sets the node-ID;
/// `paced` puts the clock on the hub's virtual time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Arguments {
    /// Stop after the self-tests.
    pub selftest: bool,
    /// The node-ID, when given (1..=127).
    pub node: Option<NodeId>,
    /// Panic right after the self-tests (`crash`), to check that a panic ends the emulated
    /// run with failure instead of hanging.
    pub crash: bool,
    /// The clock follows the emulated network's virtual time, granted by the hub (`paced`,
    /// given by `cargo xtask run` and `e2e`); otherwise it is the host's.
    pub paced: bool,
    /// A word that was not understood (the run refuses to start).
    pub unknown: bool,
}

/// Parses an emulated run's command line. Without any `arg=`, QEMU's command line is the
/// image's path: a first word with a `/` in it is that, not an argument.
pub fn parse_arguments(line: &[u8]) -> Arguments {
    let mut arguments = Arguments::default();
    for (index, word) in line
        .split(|&b| b == b' ' || b == 0)
        .filter(|w| !w.is_empty())
        .enumerate()
    {
        if index == 0 && word.contains(&b'/') {
            continue;
        }
        if word == b"selftest" {
            arguments.selftest = true;
        } else if word == b"crash" {
            arguments.crash = true;
        } else if word == b"paced" {
            arguments.paced = true;
        } else if let Some(value) = word.strip_prefix(b"node=") {
            let id = core::str::from_utf8(value)
                .ok()
                .and_then(|text| text.parse::<u8>().ok())
                .and_then(|raw| NodeId::new(raw).ok());
            match id {
                Some(id) => arguments.node = Some(id),
                None => arguments.unknown = true,
            }
        } else {
            arguments.unknown = true;
        }
    }
    arguments
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn emulated_run_arguments() {
        assert_eq!(parse_arguments(b""), Arguments::default());
        let both = parse_arguments(b"node=33 selftest");
        assert!(both.selftest && !both.unknown);
        assert_eq!(both.node.map(NodeId::raw), Some(33));
        assert!(parse_arguments(b"node=0").unknown);
        assert!(parse_arguments(b"node=128").unknown);
        assert!(parse_arguments(b"node=x").unknown);
        assert!(parse_arguments(b"verbose").unknown);
        assert!(parse_arguments(b"crash").crash);
        let paced = parse_arguments(b"node=33 paced");
        assert!(paced.paced && !paced.unknown);
        assert!(!parse_arguments(b"node=33").paced);
        let path = parse_arguments(b"target/qemu/channel-a node=2");
        assert_eq!((path.unknown, path.node.map(NodeId::raw)), (false, Some(2)));
        assert!(parse_arguments(b"node=2 target/qemu/channel-a").unknown);
    }
}
