//! The scenario files of `scenarios/` (every one, so CI covers them), the runner's own
//! checks (a failed expectation shows its measurement and the timeline), and the scenario
//! file's errors (file, line and column in a sentence).

use std::path::{Path, PathBuf};
use system_tests::scenario_runner::{self, file};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios")
}

#[test]
fn every_scenario_file_passes() {
    let files = scenario_runner::files_in(&dir()).expect("scenarios/");
    assert!(files.len() >= 20, "{} scenario files", files.len());
    let mut failed = Vec::new();
    for path in &files {
        let scenario = file::load(path).unwrap_or_else(|error| panic!("{error}"));
        let report = scenario_runner::run(&scenario).unwrap_or_else(|error| panic!("{error}"));
        if !report.passed() {
            eprintln!("{}", report.text(&scenario));
            failed.push(path.display().to_string());
        }
    }
    assert!(failed.is_empty(), "failed: {failed:?}");
}

/// At least one scenario per error class of IEC 61784-3 (EN 50325-5 Table 1) and per
/// single-channel fault class of the node, by what each file says it covers.
#[test]
fn every_error_class_and_single_channel_fault_has_a_scenario() {
    let covers: Vec<String> = scenario_runner::files_in(&dir())
        .expect("scenarios/")
        .iter()
        .map(|path| file::load(path).expect("parses").covers)
        .collect();
    let classes = [
        "IEC 61784-3 corruption",
        "IEC 61784-3 repetition",
        "IEC 61784-3 sequence",
        "IEC 61784-3 loss",
        "IEC 61784-3 delay",
        "IEC 61784-3 insertion",
        "IEC 61784-3 masquerade",
        "IEC 61784-3 addressing",
        "stuck input",
        "bit flip",
        "link loss",
        "link corruption",
        "link delay",
        "clock drift",
        "silent controller",
        "babbling controller",
        "bus-off controller",
        "no inverted frame",
    ];
    for class in classes {
        assert!(
            covers.iter().any(|covered| covered.contains(class)),
            "no scenario covers {class}"
        );
    }
}

const NETWORK: &str = "network = \"networks/estop-output.toml\"\n";

fn parse(text: &str) -> Result<file::Scenario, safety_config::network_file::FileError> {
    file::parse(text, "bad.toml", &dir())
}

/// A scenario whose bound is too tight fails that expectation, shows what was measured and
/// prints the bus frames and events around it.
#[test]
fn a_failed_expectation_shows_its_measurement_and_the_timeline() {
    let text = format!(
        "name = \"too tight\"\ncovers = \"the runner\"\n{NETWORK}run_ms = 200\n\
         [[step]]\nat_ms = 100\nfault = {{ kind = \"drop\", id = 0x102 }}\n\
         [[expect]]\nsafe = 33\nafter_ms = 100\nwithin_ms = 5\n"
    );
    let scenario = parse(&text).expect("parses");
    let report = scenario_runner::run(&scenario).expect("runs");
    assert!(!report.passed());
    let failed = report.checks.iter().find(|check| !check.passed).unwrap();
    assert_eq!(failed.line, 8);
    assert!(
        failed.measured.starts_with("safe after ") && failed.measured.contains("SRVT elapsed"),
        "{}",
        failed.measured
    );
    let timeline = report.timeline.as_deref().expect("a timeline");
    assert!(timeline.contains("bus     101"), "{timeline}");
    assert!(timeline.contains("SrvtElapsed"), "{timeline}");
    let text = report.text(&scenario);
    assert!(text.contains("FAIL line 8"), "{text}");
    assert!(text.contains("timeline around the first failure"), "{text}");
}

/// The oracle's check is part of every run: an output the producer's pairs do not justify
/// fails it even when no expectation in the file would notice.
#[test]
fn the_oracle_judges_every_scenario() {
    let text = format!(
        "name = \"oracle\"\ncovers = \"the runner\"\n{NETWORK}run_ms = 100\n\
         [[expect]]\nworking = 33\n"
    );
    let scenario = parse(&text).expect("parses");
    let report = scenario_runner::run(&scenario).expect("runs");
    let oracle = report.checks.iter().find(|check| check.line == 0).unwrap();
    assert!(oracle.passed, "{}", oracle.measured);
    assert!(
        oracle.expected.contains("node 33 SRDO 1"),
        "{}",
        oracle.expected
    );
}

#[test]
fn scenario_errors_name_the_file_line_and_column() {
    let head = format!("name = \"x\"\ncovers = \"y\"\n{NETWORK}run_ms = 300\n");
    let cases = [
        (
            "[[step]]\nat_ms = 10\ninput = { node = 2, value = 0 }\n[[expect]]\nworking = 33\n",
            (7, 9),
            "names node 2, but the network file",
        ),
        (
            "[[step]]\nat_ms = 10\nfault = { kind = \"melt\", node = 1 }\n[[expect]]\nworking = 33\n",
            (7, 18),
            "unknown variant `melt`, expected one of `drop`",
        ),
        (
            "[[expect]]\nsafe = 33\nafter_ms = 0\nwithin_ms = 5\ncause = \"bad luck\"\n",
            (9, 9),
            "cause `bad luck` is not a cause's name",
        ),
        (
            "[[step]]\nat_ms = 10\ngfc = true\nnmt = { command = \"stop\" }\n[[expect]]\nworking = 33\n",
            (5, 1),
            "exactly one of input, nmt, gfc or fault; this one has 2",
        ),
        (
            "[[step]]\nat_ms = 400\ngfc = true\n[[expect]]\nworking = 33\n",
            (5, 1),
            "after the end of the run",
        ),
        (
            "[[step]]\nat_ms = 10\nfault = { kind = \"drop\", id = 0x800 }\n[[expect]]\nworking = 33\n",
            (7, 9),
            "beyond the 11-bit identifiers",
        ),
        (
            "[[step]]\nat_ms = 10\nnmt = { command = \"halt\" }\n[[expect]]\nworking = 33\n",
            (7, 19),
            "NMT command `halt` is none of",
        ),
        ("", (1, 1), "at least one [[expect]]"),
    ];
    for (body, (line, column), words) in cases {
        let error = parse(&format!("{head}{body}")).expect_err(body);
        let text = error.to_string();
        assert!(text.starts_with("bad.toml:"), "{text}");
        assert_eq!((error.line, error.column), (line, column), "{text}");
        assert!(text.contains(words), "{text}");
    }
    let missing = parse("name = \"x\"\ncovers = \"y\"\nnetwork = \"nowhere.toml\"\nrun_ms = 1\n")
        .expect_err("no network");
    assert_eq!((missing.line, missing.column), (3, 11), "{missing}");
    assert!(missing.to_string().contains("cannot be read"), "{missing}");
}

/// A scenario counts as one the emulated network could play only when the hub's control
/// port can inject every fault it names: the hub's `drop` loses one frame, its `delay` takes
/// whole milliseconds, and the host-only faults are not the hub's.
#[test]
fn only_faults_the_hub_can_inject_make_a_scenario_the_hubs() {
    let hub_only = |name: &str| file::load(&dir().join(name)).expect("parses").hub_only();
    assert!(hub_only("loss-inverted-frame.toml"));
    assert!(hub_only("insertion-foreign-plain-frame.toml"));
    assert!(hub_only("controller-silent-producer-a.toml"));
    assert!(!hub_only("loss-every-pair.toml"), "drop with all = true");
    assert!(!hub_only("no-inverted-frame.toml"));
    assert!(!hub_only("clock-drift-consumer.toml"));
    let delay = |by_us: u64| file::FaultSpec::Delay { id: 0x102, by_us }.hub_can();
    assert!(delay(15_000));
    assert!(!delay(15_500), "the hub delays by whole milliseconds");
}
