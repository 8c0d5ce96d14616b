//! The subcommands that need no bus, only a network file or the device description: `sign`,
//! `dissector`, `eds`, `sfrt` and `budget`.

use crate::{PlanArgs, json, load};
use safety_config::ToolError;
use safety_config::calc::budget::{self, Plan};
use safety_config::calc::report;
use safety_config::calc::residual::Sil;
use safety_config::calc::sfrt::{self, DeviceTiming};
use safety_config::calc::simplecan as calc_simplecan;
use safety_config::procedure;

/// The budget's own fields, SimpleCAN's residual error rate beside them when the network
/// file has SimpleCAN.
#[derive(serde::Serialize)]
pub(crate) struct BudgetReport<'a, B, S> {
    #[serde(flatten)]
    pub(crate) budget: &'a B,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) simplecan: Option<&'a S>,
}

/// One SRDO's signature, as `sign --json` lists it.
#[derive(serde::Serialize)]
struct SrdoSignature {
    node: u8,
    srdo: u8,
    signature: u16,
}

/// One node's SimpleCAN signature with the configuration it covers.
#[derive(serde::Serialize)]
struct SimpleCanSignature<'a, C> {
    node: u8,
    signature: u32,
    configuration: &'a C,
}

/// `safety-config sign FILE`: every SRDO signature and every node's SimpleCAN signature of
/// the network file, computed offline.
pub(crate) fn sign(file: &str, as_json: bool) -> Result<bool, ToolError> {
    let network = load(file)?;
    let signatures = procedure::offline_signatures(&network);
    let simplecan = procedure::offline_simplecan(&network);
    if as_json {
        #[derive(serde::Serialize)]
        struct Signatures<'a, C> {
            srdo: Vec<SrdoSignature>,
            simplecan: Vec<SimpleCanSignature<'a, C>>,
        }
        let report = Signatures {
            srdo: signatures
                .iter()
                .map(|&(node, srdo, signature)| SrdoSignature {
                    node,
                    srdo,
                    signature,
                })
                .collect(),
            simplecan: simplecan
                .iter()
                .map(|(config, signature)| SimpleCanSignature {
                    node: config.node_id,
                    signature: *signature,
                    configuration: config,
                })
                .collect(),
        };
        println!("{}", json(&report)?);
    } else {
        for (node, srdo, value) in signatures {
            println!("node {node} SRDO {srdo}: signature {value:04X}h (0x13FF:{srdo:02X})");
        }
        for (config, value) in simplecan {
            let node = config.node_id;
            let state = if config.enabled == 1 { "on" } else { "off" };
            println!(
                "node {node} SimpleCAN ({state}, {} SDD entries): signature {value:08X}h (0x5EFF:00)",
                config.entries.len()
            );
            for entry in &config.entries {
                println!(
                    "  SC-ID {:02X}h {}: node hash {:08X}h",
                    entry.sc_id,
                    safety_config::simplecan::role_name(entry.role),
                    entry.hash
                );
            }
        }
    }
    Ok(true)
}

/// `safety-config dissector FILE`: the Wireshark Lua dissector for the file's safety frames.
pub(crate) fn dissector(file: &str) -> Result<bool, ToolError> {
    print!("{}", safety_config::dissector::lua(&load(file)?, file));
    Ok(true)
}

/// `safety-config eds [--simplecan ENTRIES [--srdos N]]`: the node's EDS from the device
/// description.
pub(crate) fn eds(simplecan: Option<u8>, srdos: Option<u8>) -> Result<bool, ToolError> {
    match simplecan {
        Some(entries) => {
            let srdos = srdos.unwrap_or(safety_device::SRDO_COUNT as u8);
            let Some(text) = safety_config::eds::simplecan_eds(entries, srdos) else {
                return Err(ToolError::Usage(format!(
                    "--srdos {srdos}: a node with SimpleCAN has no SRDOs or 2 to 4 \
                     (shared::node::SrdoAndSimpleCan)"
                )));
            };
            print!("{text}");
        }
        None => print!("{}", safety_config::eds::eds()),
    }
    Ok(true)
}

/// What `sfrt` is told of the device's timing on the command line (each part defaults to
/// the hardware's, [`DeviceTiming::HARDWARE`]).
pub(crate) struct TimingArgs {
    /// Each channel's input sample period (µs).
    pub(crate) input_sample_us: u64,
    /// The largest skew between the two contacts of one input (µs).
    pub(crate) contact_skew_us: u64,
    /// One step of a channel (µs); `None`: the step measured on the target.
    pub(crate) processing_us: Option<u64>,
    /// The output stage after the pin (µs).
    pub(crate) output_us: u64,
}

/// `safety-config sfrt FILE`: the worst-case reaction time of each safety function of the
/// file, with the device timing the command line gives.
pub(crate) fn sfrt(
    file: &str,
    plan: &PlanArgs,
    given: &TimingArgs,
    as_json: bool,
) -> Result<bool, ToolError> {
    let network = load(file)?;
    let processing_us = given.processing_us;
    let timing = DeviceTiming {
        input_sample_us: given.input_sample_us,
        contact_skew_us: given.contact_skew_us,
        processing_us: processing_us.unwrap_or(DeviceTiming::HARDWARE.processing_us),
        output_us: given.output_us,
        ..DeviceTiming::HARDWARE
    };
    let simplecan_timing = DeviceTiming {
        processing_us: processing_us.unwrap_or(DeviceTiming::HARDWARE_SIMPLECAN.processing_us),
        ..timing
    };
    let streams = sfrt::planned_streams(
        &network,
        plan.event_interval_ms.map(|ms| ms * 1000),
        &plan.traffic,
    );
    let reactions = sfrt::reactions(&network, &streams, plan.bit_rate, &timing)?;
    let simplecan = match &network.simplecan {
        Some(simplecan) => calc_simplecan::reactions(simplecan, plan.bit_rate, &simplecan_timing)
            .map_err(|error| ToolError::Usage(format!("{file}: {error}")))?,
        None => Vec::new(),
    };
    if as_json {
        #[derive(serde::Serialize)]
        struct Reactions<'a, T, R, S> {
            timing: &'a T,
            reactions: &'a R,
            simplecan_timing: &'a T,
            simplecan: &'a S,
        }
        let report = Reactions {
            timing: &timing,
            reactions: &reactions,
            simplecan_timing: &simplecan_timing,
            simplecan: &simplecan,
        };
        println!("{}", json(&report)?);
    } else {
        print!("{}", report::reactions(&reactions, plan.bit_rate, &timing));
        print!(
            "{}",
            report::simplecan_reactions(&simplecan, plan.bit_rate, &simplecan_timing)
        );
    }
    Ok(true)
}

/// `safety-config budget FILE`: the bus load per bit rate and the residual error rate
/// against `sil`; `false` (failure) when a limit is exceeded.
pub(crate) fn budget(
    file: &str,
    plan: &PlanArgs,
    sil: u8,
    devices: Option<u32>,
    as_json: bool,
) -> Result<bool, ToolError> {
    let network = load(file)?;
    let sil = Sil::from_level(sil)
        .ok_or_else(|| ToolError::Usage(format!("SIL {sil} is not 1, 2 or 3")))?;
    let plan_of = Plan {
        sil,
        devices,
        event_interval_us: plan.event_interval_ms.map(|ms| ms * 1000),
        traffic: plan.traffic.clone(),
    };
    let budget = budget::budget(&network, &plan_of, plan.bit_rate);
    let simplecan = network
        .simplecan
        .as_ref()
        .map(|simplecan| calc_simplecan::residual(simplecan, sil));
    if as_json {
        let report = BudgetReport {
            budget: &budget,
            simplecan: simplecan.as_ref(),
        };
        println!("{}", json(&report)?);
    } else {
        print!("{}", report::budget(&budget, sil));
        if let Some(simplecan) = &simplecan {
            print!("{}", report::simplecan_residual(simplecan, sil));
        }
    }
    Ok(budget.warnings.is_empty() && simplecan.is_none_or(|s| s.within()))
}
