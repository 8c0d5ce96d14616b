//! The end-to-end fault cases on the shipped images, after the nominal case
//! ([`crate::cases::nominal`]) has configured, stored and started both nodes: each fault is
//! injected where a test rig around real boards would inject it (on the bus with the hub's
//! fault vocabulary, at a contact, on the link wire), and each verdict is read where such a
//! rig reads it: node 33's two output pins and the EMCY frames on the bus. After each case
//! both nodes are reset by NMT (CiA 301 7.2.8.3.1) and started, and the next case begins
//! from nominal operation again, so that a fault left over is reported as that.
//!
//! The cases and their bounds. Virtual time adds no host jitter, so each bound is the
//! standard's time plus only what the devices themselves take, as the configuration tool's
//! reaction-time calculator counts it ([`DeviceTiming::HARDWARE`]): the producer's input
//! sample period (its SRDOs go out on a sample tick) and one processing step on each of the
//! two nodes ([`device_allowance`]):
//!
//! | case | bound |
//! |------|-------|
//! | emergency stop | the producer's refresh time: the SRDO goes out at once on the change (EN 50325-5 7.1.2) |
//! | inverted frame dropped | refresh time + SRVT (EN 50325-5 7.1.2) |
//! | inverted frame's data corrupted | refresh time: the halves are not inverse (EN 50325-5 7.1.1) |
//! | node 1 silent (both channels muted) | SCT + refresh time (EN 50325-5 7.1.2) |
//! | channel B of node 1 reads otherwise | refresh time + SRVT: B sends no inverted frame (CiA 304 9.5) |
//! | link of node 33 cut | two link periods (CiA 304 9.5: the channels' cross-monitoring) |
//!
//! "refresh time +" because a fault on the next frame waits for that frame.

use can_hub::bus::{Fault, Injection, Match};
use safety_config::calc::sfrt::DeviceTiming;
use safety_config::network_file::Network as NetworkFile;
use shared::canopen::emcy::{self, Emergency};
use shared::canopen::nmt::{self, NmtCommand};
use shared::safety::cause::Cause;
use shared::{CanFrame, Instant};

use crate::cases::{MS, event_time, mcu_indices, note_operational, wait_for_boot_ups};
use crate::network::{Event, Network};
use crate::time::Nanos;

/// The hardware layer's link heartbeat period (`board::hw::LINK_PERIOD`; a host test keeps
/// the two equal): the link is timed out after two periods without a message.
pub const LINK_PERIOD: Nanos = 10 * MS;

/// What the devices add to each case's bound: the producer's input sample period and one
/// processing step on the producer and one on the consumer, as the configuration tool's
/// calculator counts them for the hardware (`safety_config::calc::sfrt`).
pub fn device_allowance() -> Nanos {
    let timing = DeviceTiming::HARDWARE;
    (timing.input_sample_us + 2 * timing.processing_us) * 1_000
}

/// One case's reaction against its bound.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Measured {
    /// The case, in words.
    pub case: &'static str,
    /// From the fault's injection to the verdict (virtual time).
    pub reaction: Nanos,
    /// The bound.
    pub bound: Nanos,
    /// The causes the EMCY frames named, in words (node, cause).
    pub causes: Vec<(u8, Cause)>,
}

/// The timing the cases' bounds are made of, from the network file.
struct Timing {
    refresh: Nanos,
    sct: Nanos,
    srvt: Nanos,
    plain: u16,
}

impl Timing {
    fn of(file: &NetworkFile) -> Result<Timing, String> {
        let srdo = |id: u8| {
            file.nodes
                .iter()
                .find(|node| node.id == id)
                .and_then(|node| node.srdos.first())
                .map(|srdo| srdo.settings.clone())
                .ok_or_else(|| format!("the network file gives node {id} no SRDO"))
        };
        let (producer, consumer) = (srdo(1)?, srdo(33)?);
        Ok(Timing {
            refresh: Nanos::from(producer.cycle_time) * MS,
            sct: Nanos::from(consumer.cycle_time) * MS,
            srvt: Nanos::from(consumer.srvt) * MS,
            plain: (producer.cob_id_1 & 0x7FF) as u16,
        })
    }
}

/// The network and what the cases watch of it.
pub(crate) struct Rig<'a> {
    pub(crate) network: &'a mut Network,
    pub(crate) seen: &'a mut dyn FnMut(&Event),
    producer: Vec<usize>,
    consumer: Vec<usize>,
    /// The external participant that sends NMT commands (and a scenario's frames).
    pub(crate) tool: usize,
    /// The causes of the EMCY frames since the case began: (node, cause).
    causes: Vec<(u8, Cause)>,
}

impl<'a> Rig<'a> {
    /// The rig around `network` (nodes 1 and 33, two channels each), its tool joined.
    pub(crate) fn new(
        network: &'a mut Network,
        seen: &'a mut dyn FnMut(&Event),
    ) -> Result<Rig<'a>, String> {
        let producer = mcu_indices(network, 1);
        let consumer = mcu_indices(network, 33);
        if producer.len() != 2 || consumer.len() != 2 {
            return Err("the end-to-end cases need nodes 1 and 33, two channels each".into());
        }
        let tool = network.join_external("e2e");
        Ok(Rig {
            network,
            seen,
            producer,
            consumer,
            tool,
            causes: Vec::new(),
        })
    }

    /// Runs until `until` holds, at most `patience`; every frame's EMCY cause is kept.
    /// Returns when it held.
    fn run_until(
        &mut self,
        patience: Nanos,
        mut until: impl FnMut(&Network, &[(u8, Cause)]) -> bool,
    ) -> Option<Nanos> {
        let end = self.network.now() + patience;
        while self.network.now() < end {
            let step = (self.network.now() + MS).min(end);
            self.network.run_until(step);
            for event in self.network.take_events() {
                (self.seen)(&event);
                if let Event::Frame { frame, .. } = &event
                    && let Some(cause) = emcy_cause(frame)
                {
                    self.causes.push(cause);
                }
                if let Event::Stopped { .. } = event {
                    return None;
                }
                if until(self.network, &self.causes) {
                    return Some(event_time(&event));
                }
            }
            if until(self.network, &self.causes) {
                return Some(self.network.now());
            }
        }
        None
    }

    fn outputs(&self) -> Vec<bool> {
        self.consumer
            .iter()
            .map(|&mcu| self.network.output(mcu))
            .collect()
    }

    fn contacts(&mut self, closed: bool) {
        for &mcu in &self.producer {
            self.network.set_input(mcu, closed);
        }
    }

    fn nmt(&mut self, command: NmtCommand) {
        self.network.send(self.tool, nmt::command_frame(command, 0));
    }

    /// Waits for node 33's outputs to be all `on`, at most `patience`; the instant they were.
    fn outputs_become(&mut self, on: bool, patience: Nanos) -> Option<Nanos> {
        let consumer = self.consumer.clone();
        self.run_until(patience, |network, _| {
            consumer.iter().all(|&mcu| network.output(mcu) == on)
        })
    }

    /// Waits until node 33's outputs are off and an EMCY of `node` names one of `causes`.
    fn safe_with(&mut self, node: u8, causes: &[Cause], patience: Nanos) -> Option<Nanos> {
        let consumer = self.consumer.clone();
        self.run_until(patience, |network, seen| {
            consumer.iter().all(|&mcu| !network.output(mcu))
                && seen
                    .iter()
                    .any(|(from, cause)| *from == node && causes.contains(cause))
        })
    }

    /// Both nodes reset by NMT, booted, started: node 33's outputs on again with the
    /// contacts closed, and both nodes Operational in their heartbeats.
    pub(crate) fn reset(&mut self, after: &str) -> Result<(), String> {
        self.network.bus_mut().clear_faults();
        self.contacts(true);
        self.nmt(NmtCommand::ResetNode);
        wait_for_boot_ups(self.network, &[1, 33], self.seen)
            .map_err(|why| format!("after {after}, NMT reset node: {why}"))?;
        self.nmt(NmtCommand::Start);
        let mut operational = [false; 2];
        let consumer = self.consumer.clone();
        let nominal = self.run_until(3_000 * MS, |network, _| {
            consumer.iter().all(|&mcu| network.output(mcu))
        });
        // The heartbeats after the outputs came on say Operational.
        if nominal.is_some() {
            let end = self.network.now() + 1_100 * MS;
            while self.network.now() < end && operational != [true, true] {
                self.network.run_until(self.network.now() + MS);
                for event in self.network.take_events() {
                    (self.seen)(&event);
                    if let Event::Frame { frame, .. } = &event {
                        note_operational(&mut operational, frame);
                    }
                }
            }
        }
        if nominal.is_none() || operational != [true, true] {
            return Err(format!(
                "after {after}: NMT reset node and start did not bring the network back to \
                 nominal operation within 3 s (node 33's outputs {:?}, Operational heartbeats \
                 of nodes 1 and 33: {operational:?})",
                self.outputs()
            ));
        }
        self.causes.clear();
        Ok(())
    }
}

/// The node and cause an EMCY frame names (the cause is the second manufacturer-specific
/// byte on this device, `shared::canopen::emcy::Emergency::detail`; a GFC's FF01h is the
/// GFC); `None` for any other frame, and for an EMCY that clears an error (0000h).
pub(crate) fn emcy_cause(frame: &CanFrame) -> Option<(u8, Cause)> {
    let id = frame.id().raw();
    if !(0x081..=0x0FF).contains(&id) {
        return None;
    }
    let emergency = Emergency::parse(frame.data())?;
    let node = (id - 0x080) as u8;
    match emergency.code {
        emcy::code::NO_ERROR => None,
        emcy::code::GLOBAL_FAIL_SAFE => Some((node, Cause::Gfc)),
        _ => Some((node, Cause::from_code(emergency.detail[1])?)),
    }
}

/// The fault cases on a network that passed [`crate::cases::nominal`] (both nodes configured,
/// stored and started from `file`, node 1's contacts open after its emergency stop). `seen`
/// receives every event. Fails with a sentence naming the case and what was seen.
pub fn faults(
    network: &mut Network,
    file: &NetworkFile,
    seen: &mut dyn FnMut(&Event),
) -> Result<Vec<Measured>, String> {
    let timing = Timing::of(file)?;
    let mut rig = Rig::new(network, seen)?;
    let mut results = Vec::new();
    let mut record = |rig: &mut Rig<'_>,
                      case: &'static str,
                      from: Nanos,
                      at: Option<Nanos>,
                      bound: Nanos|
     -> Result<(), String> {
        let Some(at) = at else {
            return Err(format!(
                "{case}: no verdict within {:.0} ms (node 33's outputs {:?}, EMCY causes seen \
                 {:?})",
                (rig.network.now() - from) as f64 / 1e6,
                rig.outputs(),
                rig.causes
            ));
        };
        let reaction = at - from;
        let bound = bound + device_allowance();
        if reaction > bound {
            return Err(format!(
                "{case}: {:.3} ms, beyond its bound of {:.3} ms",
                reaction as f64 / 1e6,
                bound as f64 / 1e6
            ));
        }
        results.push(Measured {
            case,
            reaction,
            bound,
            causes: rig.causes.clone(),
        });
        Ok(())
    };
    let patience = |bound: Nanos| bound + 1_000 * MS;

    // The emergency stop released: the outputs come on again with no fault.
    rig.contacts(true);
    if rig.outputs_become(true, patience(timing.refresh)).is_none() {
        return Err(format!(
            "node 33's outputs did not come on again when node 1's contacts closed after the \
             emergency stop (EMCY causes seen {:?})",
            rig.causes
        ));
    }
    rig.causes.clear();

    let case = "emergency stop → node 33 outputs off";
    let from = rig.network.now();
    rig.contacts(false);
    let at = rig.outputs_become(false, patience(timing.refresh));
    record(&mut rig, case, from, at, timing.refresh)?;
    rig.contacts(true);
    if rig.outputs_become(true, patience(timing.refresh)).is_none() {
        return Err(format!(
            "node 33's outputs did not come on again when node 1's contacts closed after the \
             second emergency stop (EMCY causes seen {:?})",
            rig.causes
        ));
    }
    rig.causes.clear();

    let after = |from: Nanos| Instant::from_micros(from / 1_000);
    let inverted = timing.plain + 1;

    let case = "inverted frame dropped → node 33 safe (SRVT)";
    let from = rig.network.now();
    rig.network.bus_mut().inject(Injection::new(
        Match::next_with_id(inverted, after(from)),
        Fault::Drop,
    ));
    let bound = timing.refresh + timing.srvt;
    let at = rig.safe_with(33, &[Cause::SrvtElapsed], patience(bound));
    record(&mut rig, case, from, at, bound)?;
    rig.reset(case)?;

    let case = "inverted frame's data corrupted → node 33 safe (not inverted)";
    let from = rig.network.now();
    rig.network.bus_mut().inject(Injection::new(
        Match::next_with_id(inverted, after(from)),
        Fault::Corrupt { byte: 0, mask: 1 },
    ));
    let bound = timing.refresh;
    let at = rig.safe_with(33, &[Cause::NotInverted], patience(bound));
    record(&mut rig, case, from, at, bound)?;
    rig.reset(case)?;

    let case = "node 1 silent → node 33 safe (SCT)";
    let from = rig.network.now();
    for mcu in rig.producer.clone() {
        rig.network.bus_mut().inject(Injection::new(
            Match::all_from(mcu, after(from)),
            Fault::Mute,
        ));
    }
    let bound = timing.sct + timing.refresh;
    let at = rig.safe_with(33, &[Cause::SctElapsed], patience(bound));
    record(&mut rig, case, from, at, bound)?;
    rig.reset(case)?;

    let case = "channel B of node 1 reads otherwise → node 33 safe (SRVT)";
    let from = rig.network.now();
    let b = rig.producer[1];
    rig.network.set_input(b, false);
    let bound = timing.refresh + timing.srvt;
    let at = rig.safe_with(33, &[Cause::SrvtElapsed], patience(bound));
    record(&mut rig, case, from, at, bound)?;
    rig.reset(case)?;

    let case = "link of node 33 cut → node 33 safe";
    let from = rig.network.now();
    for mcu in rig.consumer.clone() {
        rig.network.cut_link(mcu, true);
    }
    let bound = 2 * LINK_PERIOD;
    let at = rig.safe_with(
        33,
        &[Cause::LinkTimeout, Cause::LinkMissing, Cause::PeerSafeState],
        patience(bound),
    );
    record(&mut rig, case, from, at, bound)?;
    for mcu in rig.consumer.clone() {
        rig.network.cut_link(mcu, false);
    }
    rig.reset(case)?;

    rig.network.leave_external(rig.tool);
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`LINK_PERIOD`] is the hardware layer's: the link-cut case's bound follows the image.
    #[test]
    fn the_link_period_is_the_hardware_layers() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let hw = std::fs::read_to_string(root.join("board/src/hw.rs")).unwrap();
        let line = hw
            .lines()
            .find(|line| line.starts_with("pub const LINK_PERIOD: Duration"))
            .expect("board::hw defines LINK_PERIOD");
        let ms = LINK_PERIOD / MS;
        assert!(
            line.contains(&format!("Duration::from_millis({ms})")),
            "board::hw::LINK_PERIOD changed ({line}): update emulator::e2e::LINK_PERIOD"
        );
    }

    /// An EMCY names its node and the cause in its second manufacturer-specific byte; an
    /// error reset (0000h) and every other frame name none.
    #[test]
    fn cia301_7_2_7_3_an_emcy_frame_names_the_node_and_the_cause() {
        let frame =
            |id: u16, data: &[u8]| CanFrame::new(shared::CanId::new(id).unwrap(), data).unwrap();
        assert_eq!(
            emcy_cause(&frame(0x0A1, &[0x50, 0x82, 0x11, 1, 0x02, 0, 0, 0])),
            Some((33, Cause::SrvtElapsed))
        );
        assert_eq!(emcy_cause(&frame(0x0A1, &[0, 0, 0, 0, 0, 0, 0, 0])), None);
        assert_eq!(
            emcy_cause(&frame(0x0A1, &[0x01, 0xFF, 0x11, 0, 0, 0, 0, 0])),
            Some((33, Cause::Gfc))
        );
        assert_eq!(
            emcy_cause(&frame(0x1A1, &[0x50, 0x82, 0x11, 1, 0x02, 0, 0, 0])),
            None
        );
    }
}
