//! LSS (CiA 305) on a dual-channel node: both channels' slaves follow the tool's LSS master,
//! channel A answers for the node, channel B pairs every answer with its own, and the two
//! channels' node-IDs are compared over the link (`dual_channel::lss`). A difference is the
//! safe state with its cause in words.

use dual_channel::lss::LssMismatch;
use dual_channel::runtime::{ChannelEvent, ChannelFault};
use safety_config::lss::LssMaster;
use safety_config::network_file;
use shared::canopen::NodeId;
use shared::canopen::lss::{BitRate, BitRates, MASTER_TO_SLAVE, SLAVE_TO_MASTER};
use shared::canopen::nmt::NmtState;
use shared::safety::cause::Cause;
use shared::{Duration, Instant};
use system_tests::bus::{Fault, Injection, Match};
use system_tests::dual::{DualNetwork, Side};
use system_tests::tool_bus::SimulatedBus;

const RATES: BitRates = BitRates::of(&[BitRate::Kbit500]);

/// The node's identity as `safety_device::config` gives node-ID 5 (serial number 5), to be
/// given node-ID 40 by LSS.
const NETWORK: &str = r#"
[[node]]
id = 40
name = "LSS node"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 5 }
"#;

/// Node 5 of a dual-channel network with both channels' switches as given (`None`: all
/// open), LSS enabled before the first poll.
fn lss_node(a: Option<u8>, b: Option<u8>) -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[5]);
    let node = net.node_mut(5);
    let id = |raw: Option<u8>| raw.map(|raw| NodeId::new(raw).unwrap());
    assert!(node.a.enable_lss(id(a), RATES));
    assert!(node.b.enable_lss(id(b), RATES));
    net
}

fn faults(net: &DualNetwork) -> Vec<(Instant, Side, ChannelFault)> {
    net.log
        .iter()
        .filter_map(|(at, _, side, event)| match event {
            ChannelEvent::Fault(fault) => Some((*at, *side, *fault)),
            _ => None,
        })
        .collect()
}

#[test]
fn cia305_fig46_an_unconfigured_dual_channel_node_is_found_and_configured_on_both_channels() {
    let mut net = lss_node(None, None);
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.node(5).a.node().configured_node_id(), None);
    assert_eq!(net.node(5).a.node().nmt_state(), NmtState::Initialising);
    assert!(
        net.trace.is_empty(),
        "an unconfigured node sends nothing: {:?}",
        net.trace
    );
    let file = network_file::parse(NETWORK, "NETWORK").unwrap();
    let report = LssMaster::new(
        SimulatedBus::new(&mut net),
        std::time::Duration::from_millis(100),
    )
    .fastscan_assign(&file, true)
    .unwrap();
    assert_eq!(report.assigned.len(), 1, "{report:?}");
    net.run_for(Duration::from_millis(100));
    let forty = NodeId::new(40).ok();
    assert_eq!(net.node(5).a.node().configured_node_id(), forty);
    assert_eq!(net.node(5).b.node().configured_node_id(), forty);
    assert_eq!(net.node(5).a.lss_settings(), net.node(5).b.lss_settings());
    assert_eq!(faults(&net), [], "no mismatch between the channels");
    // Only channel A answered: every answer on the bus is A's (participant 1).
    let answers: Vec<usize> = net
        .trace
        .iter()
        .filter(|(_, frame, _)| frame.id() == SLAVE_TO_MASTER)
        .map(|(_, _, from)| *from)
        .collect();
    assert!(!answers.is_empty());
    assert!(answers.iter().all(|&from| from == 1), "{answers:?}");
    assert!(
        net.trace
            .iter()
            .any(|(_, frame, _)| frame.id().raw() == 0x700 + 40 && frame.data() == [0]),
        "boots on node-ID 40"
    );
    assert_eq!(net.node(5).a.node().nmt_state(), NmtState::PreOperational);
}

#[test]
fn cia305_and_cia304_9_5_an_lss_request_channel_b_missed_is_a_mismatch_in_words() {
    let mut net = lss_node(None, None);
    net.run_for(Duration::from_millis(100));
    let now = net.now;
    // Channel B's controller loses the first LSS request: A answers it alone.
    net.node_mut(5).receive_faults.push((
        Side::B,
        Injection::new(Match::next_with_id(MASTER_TO_SLAVE.raw(), now), Fault::Drop),
    ));
    let file = network_file::parse(NETWORK, "NETWORK").unwrap();
    let _ = LssMaster::new(
        SimulatedBus::new(&mut net),
        std::time::Duration::from_millis(100),
    )
    .fastscan_assign(&file, true);
    net.run_for(Duration::from_millis(500));
    let faults = faults(&net);
    let (_, side, fault) = faults.first().copied().expect("a fault");
    assert_eq!(side, Side::B, "{faults:?}");
    let ChannelFault::Lss(mismatch) = fault else {
        panic!("{fault:?}");
    };
    // A's unpaired answer meets B's next one (or waits out the window): either way, B says
    // that the channels' LSS answers differ.
    assert_eq!(fault.cause(), Cause::LssAnswerMismatch);
    assert!(
        matches!(
            mismatch,
            LssMismatch::Unexpected { .. } | LssMismatch::AnswerDiffers { .. }
        ),
        "{mismatch}"
    );
    assert!(!net.node(5).a.is_working() && !net.node(5).b.is_working());
}

#[test]
fn cia305_rule_3_channels_whose_switches_read_differently_never_leave_the_safe_state() {
    // Channel A reads node-ID 5 on its switches, channel B reads them all open.
    let mut net = lss_node(Some(5), None);
    net.run_for(Duration::from_millis(200));
    let faults = faults(&net);
    assert!(
        faults.iter().any(|(_, _, fault)| matches!(
            fault,
            ChannelFault::Lss(LssMismatch::NodeIdDiffers { .. })
        )),
        "{faults:?}"
    );
    let fault = faults
        .iter()
        .find_map(|(_, _, fault)| match fault {
            ChannelFault::Lss(mismatch) => Some(*mismatch),
            _ => None,
        })
        .unwrap();
    assert_eq!(fault.cause(), Cause::NodeIdMismatch);
    // Whichever channel's check came first names the other's and its own.
    let text = fault.to_string();
    assert!(
        text.starts_with("the node-ID in force differs between the channels (other ")
            && text.contains("Some(NodeId(5))")
            && text.contains("None"),
        "{text}"
    );
    assert!(!net.node(5).a.is_working() && !net.node(5).b.is_working());
}

/// The tool's `configure` with `[bus] lss_fastscan = true`: the unconfigured dual-channel
/// node is given its node-ID by LSS first, then configured on it by the whole procedure
/// (EN 50325-5 8.3.1); both channels agree throughout.
#[test]
fn cia305_configure_starts_with_lss_when_the_network_file_asks_for_it() {
    use safety_config::procedure::{self, Quiet};
    let mut net = lss_node(None, None);
    net.run_for(Duration::from_millis(100));
    let file = network_file::parse(
        &format!(
            "[bus]\nlss_fastscan = true\n{NETWORK}\n[[node.srdo]]\nnumber = 1\n\
             direction = \"transmit\"\nrefresh_time_ms = 25\nsrvt_ms = 20\n\
             cob_ids = [0x101, 0x102]\nmapping = [\"input\", \"input_inverted\"]\n"
        ),
        "NETWORK",
    )
    .unwrap();
    assert!(file.lss_fastscan);
    let mut quiet = Quiet {
        accept_identity: false,
    };
    let report = procedure::configure(
        &mut system_tests::tool_bus::client(&mut net),
        &file,
        false,
        &mut quiet,
    )
    .unwrap();
    let lss = report.lss.as_ref().expect("the fastscan ran first");
    assert_eq!(lss.assigned.len(), 1, "{lss:?}");
    assert!(report.success(), "{:?}", report.nodes);
    let forty = NodeId::new(40).ok();
    assert_eq!(net.node(5).a.node().configured_node_id(), forty);
    assert_eq!(net.node(5).b.node().configured_node_id(), forty);
    net.run_for(Duration::from_millis(100));
    assert_eq!(faults(&net), [], "no mismatch between the channels");
}

/// CiA 305 Fig. 34 and 35 on the boards' own loop (`ChannelLoop` over a simulated bxCAN):
/// configure bit timing to a rate the hardware cannot make is refused with error code 1 by
/// channel A alone; to one it can, accepted; activate bit timing then has both channels'
/// loops switch their controllers once, after the switch delay, and the node sends nothing
/// for twice the delay around the switch (rule 4).
#[test]
fn cia305_fig35_activate_bit_timing_switches_both_channels_controllers_after_the_delay() {
    activate_bit_timing_switches_both_controllers::<shared::node::SrdoTable<4>>(
        safety_device::LSS_BIT_RATES,
        BitRate::Kbit800,
        BitRate::Kbit250,
    );
}

/// The same on the SimpleCAN images' channels (SRDOs and SimpleCAN beside them), whose
/// rates are 1000 and 500 kbit/s only (a SimpleCAN packet needs them to fit its slot):
/// 250 kbit/s, which a CANopen Safety node takes, is refused with error code 1.
#[test]
fn cia305_fig35_sc_activate_bit_timing_switches_both_simplecan_channels_controllers() {
    activate_bit_timing_switches_both_controllers::<system_tests::loop_net::SimpleCanProtocol>(
        safety_device::SIMPLECAN_LSS_BIT_RATES,
        BitRate::Kbit250,
        BitRate::Kbit1000,
    );
}

/// Node 5 (switches at 5) of a loop network whose channels run `P` and offer `rates`:
/// configure bit timing to `refused`, then to `accepted`, then activate bit timing.
fn activate_bit_timing_switches_both_controllers<P>(
    rates: BitRates,
    refused: BitRate,
    accepted: BitRate,
) where
    P: dual_channel::runtime::ChannelProtocol<4>,
{
    use shared::CanFrame;
    use system_tests::loop_net::{Filtering, LoopNetwork};
    let mut net: LoopNetwork<P> = LoopNetwork::new(500_000, &[5], Filtering::Banks);
    {
        let node = net.node_mut(5);
        let five = NodeId::new(5).ok();
        assert!(node.a.enable_lss(five, rates));
        assert!(node.b.enable_lss(five, rates));
    }
    net.run_for(Duration::from_millis(100));
    let request = |data: [u8; 8]| CanFrame::new(MASTER_TO_SLAVE, &data).expect("8 bytes");
    let answers = |net: &LoopNetwork<P>, since: Instant| -> Vec<(Vec<u8>, usize)> {
        net.trace
            .iter()
            .filter(|(at, frame, _)| *at >= since && frame.id() == SLAVE_TO_MASTER)
            .map(|(_, frame, from)| (frame.data().to_vec(), *from))
            .collect()
    };
    let start = net.now;
    // Switch state global: configuration; configure bit timing `refused`, then `accepted`.
    net.bus.send(0, request([0x04, 1, 0, 0, 0, 0, 0, 0]));
    net.run_for(Duration::from_millis(10));
    net.bus
        .send(0, request([0x13, 0, refused.index(), 0, 0, 0, 0, 0]));
    net.run_for(Duration::from_millis(10));
    net.bus
        .send(0, request([0x13, 0, accepted.index(), 0, 0, 0, 0, 0]));
    net.run_for(Duration::from_millis(10));
    assert_eq!(
        answers(&net, start),
        [
            (vec![0x13, 1, 0, 0, 0, 0, 0, 0], 1),
            (vec![0x13, 0, 0, 0, 0, 0, 0, 0], 1)
        ],
        "{refused:?} refused (error code 1), {accepted:?} accepted, by channel A alone"
    );
    // Activate bit timing, switch delay 100 ms.
    net.bus.send(0, request([0x15, 100, 0, 0, 0, 0, 0, 0]));
    net.run_for(Duration::from_millis(400));
    let activated = net
        .trace
        .iter()
        .find(|(_, frame, _)| frame.id() == MASTER_TO_SLAVE && frame.data()[0] == 0x15)
        .map(|(at, _, _)| *at)
        .expect("the activate request on the bus");
    let delay = Duration::from_millis(100);
    for (side, driver) in net.node(5).drivers.iter().enumerate() {
        let [(at, rate)] = driver.switched[..] else {
            panic!("channel {side}: {:?}", driver.switched);
        };
        assert_eq!(rate, accepted, "channel {side}");
        assert!(
            at >= activated + delay && at < activated + delay + Duration::from_millis(2),
            "channel {side} switched at {at:?}, the delay after {activated:?}"
        );
    }
    let node_sent = |frame: &CanFrame| frame.id() != MASTER_TO_SLAVE;
    assert!(
        !net.trace.iter().any(|(at, frame, _)| *at > activated
            && *at < activated + delay + delay
            && node_sent(frame)),
        "the node is silent for twice the switch delay"
    );
    assert_eq!(net.node(5).a.lss_settings().bit_rate, Some(accepted));
    assert_eq!(net.node(5).a.lss_settings(), net.node(5).b.lss_settings());
    assert!(net.node(5).a.fault().is_none() && net.node(5).b.fault().is_none());
}

/// CiA 305 on a node that has just powered up: an LSS request that reaches both channels
/// before their link is up (a master scanning while the machine is switched on) is answered by
/// channel A, and channel B pairs the answer once the link is up, or takes it as uncertain: it
/// is never a mismatch. Swept over the first 40 ms after power-on.
#[test]
fn cia305_an_lss_request_in_the_start_up_window_is_no_mismatch() {
    use shared::CanFrame;
    let request = |data: [u8; 8]| CanFrame::new(MASTER_TO_SLAVE, &data).expect("8 bytes");
    for at_ms in [0u64, 1, 2, 3, 5, 8, 10, 15, 20, 30, 40] {
        let mut net = lss_node(None, None);
        net.run_until(Instant::ZERO + Duration::from_millis(at_ms));
        // Switch state global: configuration; inquire node-ID (answered: FFh, unconfigured).
        net.send_foreign(request([0x04, 1, 0, 0, 0, 0, 0, 0]));
        net.send_foreign(request([0x5E, 0, 0, 0, 0, 0, 0, 0]));
        net.run_for(Duration::from_millis(600));
        let answered = net
            .trace
            .iter()
            .filter(|(_, frame, _)| frame.id() == SLAVE_TO_MASTER && frame.data()[0] == 0x5E)
            .count();
        assert_eq!(answered, 1, "at {at_ms} ms: the inquiry answered once");
        assert_eq!(faults(&net), [], "at {at_ms} ms: no mismatch");
    }
}
