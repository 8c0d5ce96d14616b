//! Reaction times, measured: from a change on node 1 (the demo's producer) to node 33's
//! outputs (the demo's consumer, both channels in series), by three paths, at every bit rate,
//! with and without higher-priority traffic, each repeated with the change at seeded random
//! phases against the refresh cycle.
//!
//! - **Event-driven SRDO**: both channels of node 1 sample input 0 (the emergency stop
//!   pressed); the producer sends the pair at once; node 33's output goes to 0.
//! - **GFC**: a GFC (EN 50325-5 7.2.1) is queued at the moment of the change; node 33's
//!   output goes to 0 on its reception. This device has no path from an input to a GFC (it
//!   sends one on a foreign frame only), so the GFC is queued by the bus's participant 0, as
//!   node 1 would queue it: the time is the GFC's own path from the transmit queue on.
//! - **SCT expiry**: node 1 stops (both channels' frames no longer reach the bus); node 33's
//!   output goes to 0 when its SCT expires (EN 50325-5 7.1.2).
//!
//! Node 1 refreshes every 25 ms, node 33 allows SCT 50 ms and SRVT 20 ms (CiA 304's
//! pre-defined connection set, as in the demo). Higher-priority traffic: 8-byte frames on
//! identifier 0x090 (above every SRDO identifier) taking [`HIGHER_PRIORITY_SHARE`] of the bus in
//! worst-case bits.

use super::configure::{node_spec, receive, stored_image, transmit};
use super::engine::{Engine, Observer, Periodic};
use super::network::Summary;
use super::plan::worst_case_micros;
use crate::bus::{Fault, Injection, Match};
use crate::dual::{LINK_PERIOD, Side};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shared::canopen::nmt::NmtCommand;
use shared::safety::types::SrdoNumber;
use shared::{Duration, Instant};

/// Refresh time of node 1 (ms).
pub const REFRESH_MS: u16 = 25;
/// SCT of node 33 (ms).
pub const SCT_MS: u16 = 50;
/// SRVT of node 33 (ms).
pub const SRVT_MS: u8 = 20;
/// The share of the bus the higher-priority traffic takes (worst-case bits).
pub const HIGHER_PRIORITY_SHARE: f64 = 0.5;
/// Its identifier.
pub const HIGHER_PRIORITY_ID: u16 = 0x090;

/// Which path the change takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Path {
    /// Event-driven SRDO.
    EventDriven,
    /// GFC.
    Gfc,
    /// SCT expiry (the producer stops).
    SctExpiry,
}

impl Path {
    /// All three.
    pub const ALL: [Path; 3] = [Path::EventDriven, Path::Gfc, Path::SctExpiry];

    /// Its name in the report.
    pub fn name(self) -> &'static str {
        match self {
            Path::EventDriven => "event-driven SRDO",
            Path::Gfc => "GFC",
            Path::SctExpiry => "SCT expiry (producer stops)",
        }
    }
}

/// One measured case.
#[derive(Clone, Debug)]
pub struct Case {
    /// The path.
    pub path: Path,
    /// Bit rate.
    pub bit_rate: u32,
    /// With higher-priority traffic.
    pub loaded: bool,
    /// Reaction times.
    pub times: Summary,
    /// Bus load measured over the case (all traffic).
    pub load: f64,
}

/// Watches node 33's output for the value it waits for.
#[derive(Default)]
struct Watch {
    waiting: Option<(Instant, u64)>,
    measured: Option<u64>,
    bits: u64,
}

impl Observer for Watch {
    fn delivered(&mut self, _at: Instant, _frame: &shared::CanFrame, _from: usize, bits: u32) {
        self.bits += u64::from(bits);
    }
    fn output(&mut self, at: Instant, _node: usize, value: u64) {
        if let Some((since, wanted)) = self.waiting {
            if value == wanted {
                self.measured = Some(at.saturating_since(since).as_micros());
                self.waiting = None;
            }
        }
    }
}

/// Runs until the watched output reaches what it waits for, at most `limit`.
fn wait(engine: &mut Engine<Watch>, limit: Duration) -> Option<u64> {
    let give_up = engine.now + limit;
    while engine.now < give_up {
        if let Some(measured) = engine.observer.measured.take() {
            return Some(measured);
        }
        engine.run_for(Duration::from_millis(1));
    }
    engine.observer.measured.take()
}

/// Node 1 and node 33 configured and started, node 33's output up; and the node indices.
fn start(bit_rate: u32, loaded: bool) -> Result<Engine<Watch>, String> {
    let mut nodes = Vec::new();
    for spec in [
        node_spec(1, vec![transmit(1, 1, REFRESH_MS, SRVT_MS)]),
        node_spec(33, vec![receive(1, 1, SCT_MS, SRVT_MS)]),
    ] {
        let (image, _) = stored_image(&spec)
            .map_err(|error| format!("configuring node {}: {error}", spec.id))?;
        nodes.push((spec.id, Some(image)));
    }
    let mut engine = Engine::new(bit_rate, nodes, LINK_PERIOD, Watch::default());
    if loaded {
        let frame = worst_case_micros(8, bit_rate);
        let period = (frame as f64 / HIGHER_PRIORITY_SHARE).ceil() as u64;
        engine.add_sender(Periodic {
            id: HIGHER_PRIORITY_ID,
            len: 8,
            period: Duration::from_micros(period),
            first: Instant::ZERO,
        });
    }
    if !engine.wait_for_boot(Duration::from_millis(2000)) {
        return Err("nodes 1 and 33 did not boot".into());
    }
    engine.watch(1, SrdoNumber::FIRST);
    engine.set_inputs(0, 1, 1);
    restart(&mut engine)?;
    Ok(engine)
}

/// NMT start, and node 33's output up.
fn restart(engine: &mut Engine<Watch>) -> Result<(), String> {
    engine.observer.waiting = Some((engine.now, 1));
    engine.nmt(NmtCommand::Start, 0);
    wait(engine, Duration::from_millis(3000))
        .map(|_| ())
        .ok_or_else(|| "node 33's output did not come up after the NMT start".into())
}

/// Measures `repetitions` changes along `path` at `bit_rate`.
pub fn measure(
    path: Path,
    bit_rate: u32,
    loaded: bool,
    repetitions: u32,
    seed: u64,
) -> Result<Case, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut engine = start(bit_rate, loaded)?;
    let mut times = Summary::default();
    let bits_before = engine.observer.bits;
    let from = engine.now;
    let limit = Duration::from_millis(u64::from(SCT_MS) * 4);
    for repetition in 0..repetitions {
        // Settle, then the change at a random phase against the refresh cycle.
        let phase = rng.random_range(0..u64::from(REFRESH_MS) * 1000);
        engine.run_for(Duration::from_micros(50_000 + phase));
        let now = engine.now;
        engine.observer.waiting = Some((now, 0));
        match path {
            Path::EventDriven => engine.set_inputs(0, 0, 0),
            Path::Gfc => engine.send_from_tool(shared::safety::gfc::frame()),
            Path::SctExpiry => {
                for side in [Side::A, Side::B] {
                    engine.bus.inject(Injection::new(
                        Match::all_from(Engine::<Watch>::participant(0, side), now),
                        Fault::Mute,
                    ));
                }
            }
        }
        let measured = wait(&mut engine, limit).ok_or_else(|| {
            format!(
                "{} at {bit_rate} bit/s, repetition {repetition}: node 33's output stayed up",
                path.name()
            )
        })?;
        times.add(measured);
        match path {
            Path::EventDriven => {
                engine.run_for(Duration::from_millis(50));
                engine.observer.waiting = Some((engine.now, 1));
                engine.set_inputs(0, 1, 1);
                wait(&mut engine, limit).ok_or("node 33's output did not come back")?;
            }
            Path::Gfc | Path::SctExpiry => {
                engine.bus.clear_faults();
                engine.run_for(Duration::from_millis(50));
                engine.nmt(NmtCommand::ResetCommunication, 0);
                engine.run_for(Duration::from_millis(50));
                restart(&mut engine)?;
            }
        }
    }
    let elapsed = engine.now.saturating_since(from).as_micros() as f64 / 1e6;
    let load = (engine.observer.bits - bits_before) as f64 / (f64::from(bit_rate) * elapsed);
    Ok(Case {
        path,
        bit_rate,
        loaded,
        times,
        load,
    })
}

/// Every case: three paths, four bit rates, without and with higher-priority traffic.
pub fn measure_all(repetitions: u32, seed: u64) -> Result<Vec<Case>, String> {
    let mut cases = Vec::new();
    for path in Path::ALL {
        for bit_rate in crate::bus::BIT_RATES {
            for loaded in [false, true] {
                cases.push(measure(path, bit_rate, loaded, repetitions, seed)?);
            }
        }
    }
    Ok(cases)
}
