//! The SPIN model (`dual-channel/model/dual_channel.pml`) holds the real values of the
//! constants it mirrors; these tests fail when one changes in Rust without the model.
//!
//! Each mirrored constant is a `#define NAME value` line in the model. Constants a public
//! item of this crate or of `shared` carries are compared with that item; the few that are
//! private to another crate (a board's link period, a role's slot counts) are read from the
//! one line of its source that declares them, so that the test names the file to look at.

use dual_channel::crosscheck::DEPTH;
use dual_channel::runtime::{INPUT_DISCREPANCY, SAMPLE_WINDOW};
use shared::safety::config::SafetyConfig;
use std::path::{Path, PathBuf};

/// The repository's root (this crate is one level below it).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the crate lies in the workspace")
        .to_path_buf()
}

/// The model's source.
fn model() -> String {
    let path = root().join("dual-channel/model/dual_channel.pml");
    std::fs::read_to_string(&path)
        .unwrap_or_else(|error| panic!("the model {} cannot be read: {error}", path.display()))
}

/// The value of the model's `#define name value` line.
fn defined(model: &str, name: &str) -> u64 {
    let value = model
        .lines()
        .filter_map(|line| line.trim().strip_prefix("#define "))
        .find_map(|rest| {
            let mut words = rest.split_whitespace();
            (words.next() == Some(name)).then(|| words.next()).flatten()
        })
        .unwrap_or_else(|| panic!("the model has no `#define {name}` line"));
    value
        .parse()
        .unwrap_or_else(|_| panic!("the model's {name} is `{value}`, not a number"))
}

/// The one line of `file` (relative to the root) that contains `anchor`, trimmed.
fn source_line(file: &str, anchor: &str) -> String {
    let path = root().join(file);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|error| panic!("{} cannot be read: {error}", path.display()));
    let lines: Vec<&str> = text.lines().filter(|line| line.contains(anchor)).collect();
    match lines.as_slice() {
        [line] => line.trim().to_string(),
        _ => panic!(
            "{file} has {} lines with `{anchor}`, not one: the model's mirror of it must be \
             checked by hand and this test updated",
            lines.len()
        ),
    }
}

/// The number in `line` between `before` and `after`.
fn number_between(line: &str, before: &str, after: &str) -> u64 {
    line.split_once(before)
        .and_then(|(_, rest)| rest.split_once(after))
        .and_then(|(number, _)| number.trim().parse().ok())
        .unwrap_or_else(|| panic!("no number between `{before}` and `{after}` in `{line}`"))
}

/// CiA 304 9.5: the sample window and the input discrepancy time the model's channels
/// apply are the runtime's.
#[test]
fn cia304_9_5_model_mirrors_the_sample_window_and_input_discrepancy() {
    let model = model();
    assert_eq!(
        defined(&model, "SAMPLE_WINDOW_US"),
        SAMPLE_WINDOW.as_micros(),
        "runtime::SAMPLE_WINDOW changed: update SAMPLE_WINDOW_US in the model and rerun \
         cargo xtask spin"
    );
    assert_eq!(
        defined(&model, "INPUT_DISCREPANCY_US"),
        INPUT_DISCREPANCY.as_micros(),
        "runtime::INPUT_DISCREPANCY changed: update INPUT_DISCREPANCY_US in the model"
    );
}

/// CiA 304 9.5 (EN 50325-5 Annex A.4): the link period of the hardware boards and the runtime's link
/// time-out (a multiple of the period) are the model's.
#[test]
fn cia304_9_5_model_mirrors_the_link_period_and_time_out() {
    let model = model();
    let period = source_line("board/src/hw.rs", "pub const LINK_PERIOD: Duration");
    assert_eq!(
        defined(&model, "LINK_PERIOD_US"),
        number_between(&period, "from_millis(", ")") * 1000,
        "board::hw::LINK_PERIOD changed (`{period}`): update LINK_PERIOD_US in the model"
    );
    let timeout = source_line("dual-channel/src/runtime.rs", "* link_period.as_micros()");
    assert_eq!(
        defined(&model, "LINK_TIMEOUT_FACTOR"),
        number_between(&timeout, "from_micros(", "*"),
        "Runtime::around's link time-out changed (`{timeout}`): update LINK_TIMEOUT_FACTOR"
    );
}

/// EN 50325-5 Table 5: the refresh time, SCT and SRVT of the pre-defined connection set,
/// which the model's producer and consumer use, and the producer's start delay.
#[test]
fn en50325_5_table5_model_mirrors_the_predefined_srdo_times() {
    let model = model();
    let producer = SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
    let consumer = SafetyConfig::<1>::predefined(33, &[], &[0x6200_0108, 0x6201_0108]);
    assert_eq!(
        defined(&model, "REFRESH_US"),
        u64::from(producer.srdos[0].cycle_time) * 1000,
        "the pre-defined refresh time changed: update REFRESH_US in the model"
    );
    assert_eq!(
        defined(&model, "SCT_US"),
        u64::from(consumer.srdos[0].cycle_time) * 1000,
        "the pre-defined SCT changed: update SCT_US in the model"
    );
    assert_eq!(
        defined(&model, "SRVT_US"),
        u64::from(consumer.srdos[0].srvt) * 1000,
        "the pre-defined SRVT changed: update SRVT_US in the model"
    );
    let start = source_line(
        "shared/src/safety/srdo.rs",
        "next: now + Duration::from_micros(",
    );
    assert_eq!(
        defined(&model, "PRODUCER_START_US"),
        number_between(&start, "from_micros(", "*"),
        "srdo::Producer::start's delay per node-ID changed (`{start}`): update PRODUCER_START_US"
    );
}

/// CiA 304 9.5: the queue and slot sizes the model's channels have are the Rust's: the
/// verdict queue depth, channel B's announcement slots, channel A's awaited pairs and the
/// runtime's frames kept from before Operational.
#[test]
fn cia304_9_5_model_mirrors_the_queue_and_slot_sizes() {
    let model = model();
    assert_eq!(
        defined(&model, "VERDICT_DEPTH"),
        DEPTH as u64,
        "crosscheck::DEPTH changed: update VERDICT_DEPTH in the model"
    );
    let announced = source_line("channel-b/src/role.rs", "announced: FrameSlots<");
    assert_eq!(
        defined(&model, "ANNOUNCED_SLOTS"),
        number_between(&announced, "FrameSlots<", ">"),
        "channel B's announcement slots changed (`{announced}`): update ANNOUNCED_SLOTS"
    );
    let awaiting = source_line("channel-a/src/role.rs", "awaiting: [Option<Awaited>;");
    assert_eq!(
        defined(&model, "AWAITED_SLOTS"),
        number_between(&awaiting, ";", "]"),
        "channel A's awaited pairs changed (`{awaiting}`): update AWAITED_SLOTS"
    );
    let early = source_line(
        "dual-channel/src/runtime.rs",
        "early: heapless::Vec<(Instant, CanFrame),",
    );
    assert_eq!(
        defined(&model, "EARLY_SLOTS"),
        number_between(&early, "CanFrame),", ">"),
        "Runtime::early's size changed (`{early}`): update EARLY_SLOTS"
    );
}

/// The names of the constants the tests above compare with Rust.
const COMPARED: [&str; 12] = [
    "SAMPLE_WINDOW_US",
    "INPUT_DISCREPANCY_US",
    "LINK_PERIOD_US",
    "LINK_TIMEOUT_FACTOR",
    "REFRESH_US",
    "SCT_US",
    "SRVT_US",
    "PRODUCER_START_US",
    "VERDICT_DEPTH",
    "ANNOUNCED_SLOTS",
    "EARLY_SLOTS",
    "AWAITED_SLOTS",
];

/// CiA 304 9.5: every constant in the model's block of mirrored constants is one the tests
/// above compare with Rust, so that a constant mirrored later cannot go unchecked.
#[test]
fn cia304_9_5_every_constant_the_model_mirrors_is_compared_with_rust() {
    let model = model();
    let block = model
        .split_once("Mirrored constants")
        .and_then(|(_, rest)| rest.split_once("Model bounds"))
        .map(|(block, _)| block)
        .expect("the model has its block of mirrored constants before its bounds");
    let mirrored: Vec<&str> = block
        .lines()
        .filter_map(|line| line.trim().strip_prefix("#define "))
        .filter_map(|rest| rest.split_whitespace().next())
        .collect();
    let unchecked: Vec<&&str> = mirrored
        .iter()
        .filter(|name| !COMPARED.contains(name))
        .collect();
    assert!(
        unchecked.is_empty(),
        "the model mirrors {unchecked:?}, which no test compares with Rust: add the comparison"
    );
    for name in COMPARED {
        assert!(
            mirrored.contains(&name),
            "{name} is compared with Rust but is not in the model's block of mirrored constants"
        );
    }
}
