//! The SimpleCAN end-to-end cases on the shipped SimpleCAN images (`cargo xtask e2e
//! --protocol simplecan`, and part of `cargo xtask test`): the four sealed hardware images on
//! the emulated STM32F405s ([`crate::network`]), faults injected through the emulated
//! network's control port, every verdict read from the channels' status reports as the
//! emulator observes them. CANopen Safety's end-to-end cases run inside the emulator
//! (`emulator::cases`, `emulator::e2e`: `cargo xtask e2e`).
//!
//! Bounds: the calculator's (`safety_config::calc::simplecan::reactions`, as `safety-config
//! sfrt` gives them for `scenarios/networks/simplecan.toml`), plus a margin for the status
//! report that tells us, [`MARGIN_MS`]:
//!
//! | case | the calculator's bound | bound here |
//! |------|------------------------|------------|
//! | emergency stop pressed | fault-free reaction (slot wait, packet, buffering, cross-check) | that + margin |
//! | node 1 stopped (both channels muted) | one fault: the consumer's safety timeout (SC_REQ_20) and the steps around it | that + margin |

use crate::network::{self, Network, output_33, working};
use anyhow::{Result, bail};
use shared::safety::cause::Cause;
use std::time::Duration;

/// The margin on top of each bound (see the module documentation): the status reports
/// come every 250 ms at the latest, at once on a change.
pub const MARGIN_MS: u64 = 150;

/// One case's measured time against its bound.
pub struct Measured {
    /// The case.
    pub case: &'static str,
    /// What happened, in milliseconds after the cause (hub time).
    pub ms: f64,
    /// The bound.
    pub bound_ms: u64,
}

/// Waits until node 33 is safe (both channels not working, output 0), one channel reporting
/// one of `causes` and the other that too or 40h (told by the first over the link); returns
/// the time after `since` (hub seconds), in milliseconds.
fn node_33_safe(network: &mut Network, since: f64, causes: &[Cause], bound_ms: u64) -> Result<f64> {
    let patience = Duration::from_millis(bound_ms + 2_000);
    let at = network.wait_for(patience, |latest| {
        ["node33a", "node33b"].iter().all(|name| {
            latest
                .get(*name)
                .is_some_and(|(_, s)| !s.working && s.output == 0)
        }) && {
            // The channel that found the fault first reports it; the other may report that
            // (the same cause when both found it, 40h when it was told first over the link).
            let cause = |name: &str| latest.get(name).map(|(_, s)| s.cause);
            let found = |cause: Option<u8>| {
                cause
                    .and_then(Cause::from_code)
                    .is_some_and(|c| causes.contains(&c))
            };
            let told =
                |cause: Option<u8>| found(cause) || cause == Some(Cause::PeerSafeState.code());
            let (a, b) = (cause("node33a"), cause("node33b"));
            (found(a) && told(b)) || (found(b) && told(a))
        }
    })?;
    let Some(at) = at else {
        bail!(
            "node 33 did not reach its safe state (one channel's cause one of {causes:?}, the other's that or 40h) within {} ms:\n{}",
            bound_ms + 2_000,
            network.table()
        );
    };
    Ok((at - since) * 1000.0)
}

/// Presses the emergency stop on node 1 (both contacts open); returns the milliseconds until
/// node 33's output is 0 in both channels.
pub fn press(network: &mut Network) -> Result<f64> {
    let pressed = network.command("input node1a 0")?;
    network.command("input node1b 0")?;
    let off = network.wait_for(Duration::from_secs(3), |latest| {
        output_33(latest) == Some(0)
    })?;
    match off {
        Some(off) => Ok((off - pressed) * 1000.0),
        None => bail!(
            "node 33's output stayed on after the emergency stop:\n{}",
            network.table()
        ),
    }
}

/// Releases the emergency stop; waits until node 33's output is on again.
pub fn release(network: &mut Network) -> Result<()> {
    network.command("input node1a 1")?;
    network.command("input node1b 1")?;
    let on = network.wait_for(Duration::from_secs(3), |latest| {
        output_33(latest) == Some(1)
    })?;
    if on.is_none() {
        bail!(
            "node 33's output stayed off after release:\n{}",
            network.table()
        );
    }
    Ok(())
}

/// Waits until both nodes work and node 33 validates node 1's SRDOs again: every case starts
/// from there, so that a fault left over from the previous one is reported as that, not as
/// the next case's failure.
pub fn nominal(network: &mut Network, when: &str) -> Result<()> {
    let before = network
        .control
        .latest
        .get("node33a")
        .map_or(0, |(_, s)| s.validated);
    let flowing = network.wait_for(Duration::from_secs(3), |latest| {
        working(latest, 1)
            && working(latest, 33)
            && latest
                .get("node33a")
                .is_some_and(|(_, s)| s.validated >= before.wrapping_add(5))
    })?;
    if flowing.is_none() {
        bail!(
            "{when}: the network did not reach nominal operation (both nodes working, node 33 \
             validating {}) within 3 s:\n{}",
            network.protocol.stream(),
            network.table()
        );
    }
    Ok(())
}

/// The calculator's bounds for the SimpleCAN network, milliseconds rounded up: node 33's
/// fault-free reaction to node 1's input, and its one-fault reaction (the packet after the
/// demand lost: the safety timeout).
fn simplecan_bounds() -> Result<(u64, u64)> {
    use safety_config::calc::sfrt::DeviceTiming;
    let file = safety_config::network_file::parse(
        network::SIMPLECAN_NETWORK_FILE,
        "scenarios/networks/simplecan.toml",
    )?;
    let Some(simplecan) = file.simplecan else {
        bail!("scenarios/networks/simplecan.toml has no [simplecan] section");
    };
    let reactions = safety_config::calc::simplecan::reactions(
        &simplecan,
        safety_device::BIT_RATE,
        &DeviceTiming::HARDWARE,
    )?;
    let Some(reaction) = reactions
        .iter()
        .find(|r| r.consumer == 33 && r.sc_id == network::ESTOP_SC_ID)
    else {
        bail!("the calculator gives no reaction of node 33 to SC-ID 30h");
    };
    Ok((
        reaction.fault_free_us.div_ceil(1000),
        reaction.one_fault_us.div_ceil(1000),
    ))
}

/// The SimpleCAN cases on one network speaking SimpleCAN ([`network::Protocol::Simplecan`]):
/// the emergency stop twice (SC_REQ_05: node 33's output 0 within the calculator's
/// fault-free reaction plus [`MARGIN_MS`], on again after the release), then node 1 stopped
/// (both channels muted: the master and the producer gone), node 33 in its safe state with
/// its value's timeout, 6Ah (SC_REQ_20, SC_REQ_40), within the one-fault reaction plus the
/// margin. Times are the emulated network's (its virtual time).
pub fn run_simplecan(network: &mut Network) -> Result<Vec<Measured>> {
    let (reaction_ms, timeout_ms) = simplecan_bounds()?;
    let mut results = Vec::new();
    let mut check = |case: &'static str, ms: f64, bound_ms: u64| -> Result<()> {
        println!("   {case}: {ms:.1} ms (bound {bound_ms} ms)");
        if ms > bound_ms as f64 {
            bail!("{case}: {ms:.1} ms exceeds its bound of {bound_ms} ms");
        }
        results.push(Measured { case, ms, bound_ms });
        Ok(())
    };
    nominal(network, "at the start")?;
    println!(
        "   nominal: both nodes Operational, node 33 confirms {}, output on",
        network.protocol.stream()
    );
    let bound = reaction_ms + MARGIN_MS;
    let latency = press(network)?;
    check(
        "SimpleCAN emergency stop → node 33 output 0",
        latency,
        bound,
    )?;
    release(network)?;
    let latency = press(network)?;
    check("SimpleCAN emergency stop again", latency, bound)?;
    release(network)?;
    nominal(network, "after the release")?;

    let at = network.command("mute node1a")?;
    network.command("mute node1b")?;
    let bound = timeout_ms + MARGIN_MS;
    let ms = node_33_safe(network, at, &[Cause::SimpleCanTimeout], bound)?;
    check(
        "node 1 (the master) stopped → node 33 safe (6Ah, timeout)",
        ms,
        bound,
    )?;
    Ok(results)
}

/// The share of the bus, in percent, that the traffic other than SRDOs fills in the case under
/// bus load (`emulate-network --load`: node 33's SDO answers included).
pub const LOAD_PERCENT: u32 = 30;
/// How long the load is kept up (the network's time) in the full case, `cargo xtask e2e
/// --bus-load`.
pub const LOAD_SECONDS: f64 = 60.0;
/// How long it is kept up in CI (`cargo xtask test`, `--bus-load-seconds`): 100 pairs of
/// SRDO 1 at the emulated network's refresh time of 100 ms. What it measured:
/// `docs/emulated-figures.md`.
pub const CI_LOAD_SECONDS: f64 = 10.0;
/// `cargo xtask e2e --protocol simplecan`: the SimpleCAN cases ([`run_simplecan`]) on the
/// shipped SimpleCAN images; fails on a case over its bound and on a channel whose deepest
/// stack is above the RAM budget's reserve.
pub fn simplecan(root: &std::path::Path) -> Result<()> {
    let mut network = Network::start_for(root, network::Protocol::Simplecan)?;
    println!("\n## End-to-end tests of the shipped SimpleCAN images on the emulated network");
    let outcome = run_simplecan(&mut network);
    let measured = network.measured_summary();
    let stack = network.worst(|s| s.stack_used);
    let discarded = network.worst(|s| s.discarded);
    let dir = network.dir().to_path_buf();
    let _ = network.stop()?;
    if let Ok(results) = &outcome {
        println!("\n| case | measured | bound |\n|---|---:|---:|");
        for Measured { case, ms, bound_ms } in results {
            println!("| {case} | {ms:.1} ms | {bound_ms} ms |");
        }
    }
    println!("   {measured}");
    println!(
        "   most SRDO frames one channel discarded as CAN double reception (since its last \
         reset): {discarded}"
    );
    println!("   traces and logs: {}", dir.display());
    outcome?;
    if u64::from(stack) > crate::images::STACK_RESERVE {
        bail!(
            "a channel used {stack} bytes of stack, more than the {} bytes the RAM budget \
             reserves for it (`STACK_RESERVE` in xtask/src/images.rs)",
            crate::images::STACK_RESERVE
        );
    }
    Ok(())
}
