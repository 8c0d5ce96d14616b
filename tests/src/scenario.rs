//! The demo scenario: an emergency-stop node (node 1, SRDO producer) and a safe output node
//! (node 33, SRDO consumer) on one bus, configured by a tool over SDO, then an emergency stop
//! and three injected faults. Each step states what must happen, and the run checks it.
//!
//! `cargo xtask run` prints it; the system tests assert the same outcomes.

use crate::bus::{Fault, Match};
use crate::network::{Happening, Network};
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::node::Event;
use shared::safety::srdo::SrdoFaultCause;
use shared::{Duration, Instant};

/// Index of the emergency-stop node (node-ID 1) in the network.
pub const ESTOP: usize = 0;
/// Index of the safe output node (node-ID 33).
pub const OUTPUT_NODE: usize = 1;

/// One checked expectation.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// What was checked.
    pub what: String,
    /// Whether it held.
    pub passed: bool,
    /// What was measured.
    pub measured: String,
}

/// The result of a run.
pub struct Run {
    /// The network as the scenario left it (log, trace, statistics).
    pub network: Network,
    /// Every expectation, in order.
    pub outcomes: Vec<Outcome>,
    /// Emergency stop pressed to output 0, simulated time.
    pub estop_latency: Option<Duration>,
}

impl Run {
    /// `true` when every expectation held.
    pub fn passed(&self) -> bool {
        self.outcomes.iter().all(|outcome| outcome.passed)
    }
}

/// Narration hook: called with each phase's heading and with the log lines it produced.
pub trait Narrator {
    /// A new phase begins.
    fn phase(&mut self, heading: &str);
    /// What happened during the phase, already formatted.
    fn happened(&mut self, lines: &str);
    /// An expectation was checked.
    fn outcome(&mut self, outcome: &Outcome);
}

/// A narrator that says nothing (for tests).
pub struct Silent;

impl Narrator for Silent {
    fn phase(&mut self, _: &str) {}
    fn happened(&mut self, _: &str) {}
    fn outcome(&mut self, _: &Outcome) {}
}

struct Script<'a> {
    net: Network,
    outcomes: Vec<Outcome>,
    narrator: &'a mut dyn Narrator,
    mark: usize,
}

impl Script<'_> {
    fn phase(&mut self, heading: &str) {
        self.flush();
        self.narrator.phase(heading);
    }

    fn flush(&mut self) {
        let lines = self.net.describe(self.mark);
        self.mark = self.net.log.len();
        if !lines.is_empty() {
            self.narrator.happened(&lines);
        }
    }

    fn check(&mut self, what: impl Into<String>, passed: bool, measured: impl Into<String>) {
        self.flush();
        let outcome = Outcome {
            what: what.into(),
            passed,
            measured: measured.into(),
        };
        self.narrator.outcome(&outcome);
        self.outcomes.push(outcome);
    }

    /// The first happening of device `index` at or after log position `since` that `matches`.
    fn first(
        &self,
        since: usize,
        index: usize,
        matches: impl Fn(&Happening) -> bool,
    ) -> Option<(Instant, Happening)> {
        self.net.log[since..]
            .iter()
            .find(|(_, device, happening)| *device == Some(index) && matches(happening))
            .map(|(at, _, happening)| (*at, happening.clone()))
    }

    fn srdo_fault(&self, since: usize) -> Option<(Instant, SrdoFaultCause)> {
        self.first(since, OUTPUT_NODE, |h| {
            matches!(h, Happening::Event(Event::SrdoFault(_)))
        })
        .and_then(|(at, happening)| match happening {
            Happening::Event(Event::SrdoFault(fault)) => Some((at, fault.cause)),
            _ => None,
        })
    }

    /// Resets node 33's communication (it reloads its stored configuration) and starts it.
    fn recover(&mut self) {
        self.net.bus.clear_faults();
        self.net.nmt(NmtCommand::ResetCommunication, 33);
        self.net.run_for(Duration::from_millis(5));
        self.net.nmt(NmtCommand::Start, 33);
        self.net.run_for(Duration::from_millis(100));
        let output = self.net.output(OUTPUT_NODE);
        self.check(
            "after NMT reset communication and start, node 33 works again",
            output == 1 && self.net.devices[OUTPUT_NODE].node.is_working(),
            format!("output {output}"),
        );
    }
}

/// Runs the demo scenario at `bit_rate`.
pub fn run(bit_rate: u32, narrator: &mut dyn Narrator) -> Run {
    let net = Network::new(bit_rate, &[(1, "e-stop node 1"), (33, "output node 33")]);
    let mut s = Script {
        net,
        outcomes: Vec::new(),
        narrator,
        mark: 0,
    };

    s.phase("Power on: both nodes boot and enter Pre-operational (CiA 301 7.3.2)");
    s.net.run_for(Duration::from_millis(10));
    let pre_op = (0..2).all(|i| s.net.state(i) == NmtState::PreOperational);
    s.check("both nodes Pre-operational", pre_op, "");

    s.phase(
        "Configuration over SDO: node 33 consumes node 1's SRDO (COB-IDs 0x101/0x102), the \
         tool reads the parameters back, signs them (EN 50325-5 6.4.1.5), sets 0x13FE = A5h and \
         stores them (0x1010)",
    );
    let configured = (|| -> Result<(), String> {
        let net = &mut s.net;
        let sdo = |error: shared::canopen::sdo_client::ClientError| format!("{error:?}");
        net.write(33, Address::new(0x1301, 1), &[0]).map_err(sdo)?;
        net.write(33, Address::new(0x1301, 5), &0x101u32.to_le_bytes())
            .map_err(sdo)?;
        net.write(33, Address::new(0x1301, 6), &0x102u32.to_le_bytes())
            .map_err(sdo)?;
        net.write(33, Address::new(0x1301, 1), &[2]).map_err(sdo)?;
        for id in [1u8, 33] {
            net.sign_and_validate(id, &[1])
                .map_err(|error| error.to_string())?;
            net.write(id, Address::new(0x1010, 1), b"save")
                .map_err(sdo)?;
        }
        Ok(())
    })();
    s.check(
        "configuration accepted, signed, validated and stored on both nodes",
        configured.is_ok(),
        format!(
            "{configured:?} at {:.1} ms",
            s.net.now.as_micros() as f64 / 1000.0
        ),
    );
    let rejected = s.net.write(33, Address::new(0x1301, 2), &[0, 0]);
    s.check(
        "an SCT of 0 is refused with abort 0609 0032h (value too low)",
        rejected
            == Err(shared::canopen::sdo_client::ClientError::Aborted(
                shared::canopen::od::AbortCode::ValueTooLow,
            )),
        format!("{rejected:?}"),
    );
    // That refused write changed nothing, but an accepted one would have reset 0x13FE.

    s.phase("Start: emergency stop released (input 1), NMT start all nodes");
    s.net.set_input(ESTOP, 1);
    s.net.nmt(NmtCommand::Start, 0);
    s.net.run_for(Duration::from_millis(300));
    let operational = (0..2).all(|i| s.net.state(i) == NmtState::Operational);
    let pairs = s.net.devices[OUTPUT_NODE].pairs_received;
    s.check("both nodes Operational", operational, "");
    s.check(
        "node 33's output follows node 1's input (1: machine enabled)",
        s.net.output(OUTPUT_NODE) == 1,
        format!("{pairs} valid SRDO pairs received in 300 ms (refresh time 25 ms)"),
    );

    s.phase("Emergency stop pressed on node 1");
    let since = s.net.log.len();
    let pressed = s.net.now;
    s.net.set_input(ESTOP, 0);
    s.net.run_for(Duration::from_millis(100));
    let off = s
        .first(since, OUTPUT_NODE, |h| *h == Happening::Output(0))
        .map(|(at, _)| at.saturating_since(pressed));
    s.check(
        "node 33's output goes to 0 within one refresh time (25 ms) plus two frame times",
        off.is_some_and(|latency| latency <= Duration::from_millis(26)),
        off.map_or("output never went to 0".into(), |latency| {
            format!(
                "press to output 0: {:.3} ms (event-driven SRDO)",
                latency.as_micros() as f64 / 1000.0
            )
        }),
    );
    let estop_latency = off;
    s.net.set_input(ESTOP, 1);
    s.net.run_for(Duration::from_millis(100));
    s.check(
        "released: the output follows again (data, not a fault, so nothing is latched)",
        s.net.output(OUTPUT_NODE) == 1,
        "",
    );

    s.phase("Fault: the bus loses the next inverted frame (0x102)");
    let since = s.net.log.len();
    let from = s.net.now;
    s.net.inject(Match::next_with_id(0x102, from), Fault::Drop);
    s.net.run_for(Duration::from_millis(100));
    let fault = s.srdo_fault(since);
    let plain = s
        .net
        .trace
        .iter()
        .find(|(at, frame)| *at >= from && frame.id().raw() == 0x101)
        .map(|(at, _)| *at);
    s.check(
        "node 33 detects the missing inverted frame within SRVT (20 ms) of its plain frame",
        matches!(fault, Some((at, SrdoFaultCause::SrvtElapsed))
            if plain.is_some_and(|p| at.saturating_since(p) <= Duration::from_millis(20))),
        match (fault, plain) {
            (Some((at, cause)), Some(p)) => format!(
                "{cause:?} {:.3} ms after the plain frame",
                at.saturating_since(p).as_micros() as f64 / 1000.0
            ),
            _ => format!("{fault:?}"),
        },
    );
    check_safe_and_latched(&mut s, since);
    s.recover();

    s.phase("Fault: a data byte of the next plain frame (0x101) is corrupted");
    let since = s.net.log.len();
    s.net.inject(
        Match::next_with_id(0x101, s.net.now),
        Fault::Corrupt {
            byte: 0,
            mask: 0x01,
        },
    );
    s.net.run_for(Duration::from_millis(100));
    let fault = s.srdo_fault(since);
    s.check(
        "node 33 finds the data not inverted, bit by bit (CiA 304 9.5)",
        matches!(fault, Some((_, SrdoFaultCause::NotInverted))),
        format!("{:?}", fault.map(|(_, cause)| cause)),
    );
    check_safe_and_latched(&mut s, since);
    s.recover();

    s.phase("Fault: node 1 falls silent (muted on the bus)");
    let since = s.net.log.len();
    let muted = s.net.now;
    s.net.inject(Match::all_from(ESTOP + 1, muted), Fault::Mute);
    s.net.run_for(Duration::from_millis(150));
    let fault = s.srdo_fault(since);
    let last_pair = s
        .net
        .trace
        .iter()
        .rev()
        .find(|(at, frame)| *at < muted && frame.id().raw() == 0x102)
        .map(|(at, _)| *at);
    s.check(
        "node 33 detects the missing SRDO within SCT (50 ms) of the last valid pair",
        matches!(fault, Some((at, SrdoFaultCause::SctElapsed))
            if last_pair.is_some_and(|p| at.saturating_since(p) <= Duration::from_millis(50))),
        match (fault, last_pair) {
            (Some((at, cause)), Some(p)) => format!(
                "{cause:?} {:.3} ms after the last pair",
                at.saturating_since(p).as_micros() as f64 / 1000.0
            ),
            _ => format!("{fault:?}"),
        },
    );
    check_safe_and_latched(&mut s, since);
    s.recover();
    s.flush();

    Run {
        network: s.net,
        outcomes: s.outcomes,
        estop_latency,
    }
}

/// After a fault: output 0, an EMCY on the bus, and the output stays 0 although valid pairs
/// arrive again (the safe state is latched, EN 50325-5 7.1.2).
fn check_safe_and_latched(s: &mut Script<'_>, since: usize) {
    let emcy = s
        .net
        .log
        .get(since..)
        .unwrap_or_default()
        .iter()
        .find_map(|(_, _, happening)| match happening {
            Happening::Emergency(33, emergency) => Some(*emergency),
            _ => None,
        });
    s.check(
        "node 33 is in the safe state (output 0) and said why in an EMCY",
        s.net.output(OUTPUT_NODE) == 0 && emcy.is_some(),
        emcy.map_or("no EMCY".into(), |e| {
            format!(
                "EMCY {:04X}h, SRDO {}, cause {}",
                e.code, e.detail[0], e.detail[1]
            )
        }),
    );
    s.net.bus.clear_faults();
    s.net.run_for(Duration::from_millis(100));
    s.check(
        "the safe state is latched while valid pairs arrive again",
        s.net.output(OUTPUT_NODE) == 0 && !s.net.devices[OUTPUT_NODE].node.is_working(),
        "",
    );
}
