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

mod emulated {
    //! The emulated network's half of the runner, on recorded observations (no emulated MCU):
    //! each step as the hub's control command, and the expectations judged from status
    //! reports and the bus frames on the network's clock.

    use super::dir;
    use can_hub::events::Event;
    use emulation_wire::Status;
    use shared::safety::cause::Cause;
    use system_tests::scenario_runner::emulated::{self, Observed};
    use system_tests::scenario_runner::file::{self, Channel, FaultSpec, Stimulus};

    fn emulated_scenario(name: &str) -> file::Scenario {
        file::load(&dir().join("emulated").join(name)).unwrap_or_else(|error| panic!("{error}"))
    }

    fn status(working: bool, output: u8, cause: Cause) -> Status {
        Status {
            nmt: 5,
            working,
            link_up: true,
            output,
            input: 1,
            cause: cause.code(),
            ..Status::default()
        }
    }

    /// A hand-made event log of the emulated network (`can_hub::events`): the tool starts all
    /// nodes at `nmt` s, node 1's channels send released (01h, FEh) every 100 ms from
    /// 100 ms later until `until` s, the inverted frame of the pair at `lost` s lost, then
    /// `tail`; node 33's channels report their output on 10 ms after the first pair.
    fn event_log(nmt: f64, until: f64, lost: Option<f64>, tail: &str) -> Vec<Event> {
        let micros = |seconds: f64| (seconds * 1e6).round() as u64;
        let t = |micros: u64| format!("{}.{:06}", micros / 1_000_000, micros % 1_000_000);
        let mut text = format!("frame t={} from=tool6 000#0100\n", t(micros(nmt)));
        let mut plain = micros(nmt) + 100_000;
        while plain <= micros(until) {
            text += &format!("frame t={} from=node1a 101#01\n", t(plain));
            if lost.map(micros) != Some(plain) {
                text += &format!("frame t={} from=node1b 102#FE\n", t(plain + 300));
            }
            if plain == micros(nmt) + 100_000 {
                text += &format!("output t={} node33a 1\n", t(plain + 10_000));
                text += &format!("output t={} node33b 1\n", t(plain + 10_000));
            }
            plain += 100_000;
        }
        text += tail;
        let mut events = can_hub::events::parse(&text).expect("the log reads");
        events.sort_by_key(Event::at);
        events
    }

    /// Node 33 working from 9.9 s (both channels), the step at 200 ms applied late at
    /// 10.25 s (start 10.0 s), then channel B safe first, telling channel A (40h), which
    /// reports at 10.47 s. The event log: node 1's pairs from 9.1 s, the inverted frame at
    /// 10.3 s lost, node 33's output off at 10.44 s (SRVT elapsed at 10.4 s: within the
    /// emulation's allowance).
    fn srvt_case() -> Observed {
        let on = status(true, 1, Cause::None);
        Observed {
            start: 10.0,
            applied: vec![10.25],
            statuses: vec![
                ("node33a".into(), 9.9, on),
                ("node33b".into(), 9.9, on),
                (
                    "node33a".into(),
                    10.44,
                    status(false, 0, Cause::PeerSafeState),
                ),
                (
                    "node33b".into(),
                    10.46,
                    status(false, 0, Cause::SrvtElapsed),
                ),
            ],
            frames: Vec::new(),
            end: 10.8,
            events: event_log(
                9.0,
                10.3,
                Some(10.3),
                "output t=10.440000 node33a 0\noutput t=10.460000 node33b 0\n",
            ),
            judged_from: 0.0,
        }
    }

    /// The safe state is measured from when the hub took the step's command, not from its
    /// scheduled time, to the report that shows both channels safe; the cause is the one a
    /// channel found itself, not "other channel safe" (40h).
    #[test]
    fn a_safe_expectation_is_measured_from_the_step_as_the_hub_applied_it() {
        let scenario = emulated_scenario("loss-inverted-frame.toml");
        let report = emulated::judge(&scenario, &srvt_case());
        assert!(report.passed(), "{}", report.text(&scenario));
        let safe = &report.checks[1];
        assert_eq!(
            safe.measured, "safe after 210.000 ms, cause SRVT elapsed",
            "{}",
            safe.measured
        );
        assert!(report.text(&scenario).contains("on the emulated network"));
        let oracle = report.checks.last().expect("the oracle's check");
        assert!(
            oracle.measured.ends_with(
                "the safe state first required at t = 400.000 ms (SRVT elapsed with a plain \
                 frame pending), the output off 40.000 ms later (allowed 41.000 ms)"
            ),
            "{}",
            oracle.measured
        );
        // A scenario after an NMT reset of all nodes and their start again: the first
        // requirement named is the one since the reset, not the scenario's before.
        let mut later = srvt_case();
        later.events.extend(
            can_hub::events::parse(
                "frame t=10.500000 from=tool6 000#8100\nframe t=10.600000 from=tool6 000#0100\n\
                 frame t=10.700000 from=node1a 101#01\nframe t=10.750000 from=tool6 001#\n",
            )
            .expect("the log reads"),
        );
        later.judged_from = 10.55;
        later.start = 10.62;
        let report = emulated::judge(&scenario, &later);
        let oracle = report.checks.last().expect("the oracle's check");
        assert!(
            oracle
                .measured
                .contains("first required at t = 130.000 ms (GFC on the bus)"),
            "{}",
            oracle.measured
        );
    }

    /// Too late, or the wrong cause, fails with the measurement and prints the reports and
    /// frames around it.
    #[test]
    fn a_late_safe_state_fails_with_its_measurement_and_the_timeline() {
        let scenario = emulated_scenario("loss-inverted-frame.toml");
        let mut late = srvt_case();
        late.statuses[3].1 = 10.61;
        late.end = 11.0;
        let report = emulated::judge(&scenario, &late);
        assert!(!report.passed());
        let failed = report.checks.iter().find(|check| !check.passed).unwrap();
        assert_eq!(failed.measured, "safe after 360.000 ms, cause SRVT elapsed");
        let timeline = report.timeline.as_deref().expect("a timeline");
        assert!(
            timeline.contains("status  node33b: nmt=5 SAFE"),
            "{timeline}"
        );
        assert!(report.text(&scenario).contains("FAIL line 21"));

        let mut wrong = srvt_case();
        wrong.statuses[3].2.cause = Cause::SctElapsed.code();
        let report = emulated::judge(&scenario, &wrong);
        assert!(!report.passed(), "SCT is not the SRVT the file expects");
    }

    /// A node that leaves the working state fails `working`, and an EMCY in the trace
    /// fails `no_emcy`, each saying when.
    #[test]
    fn working_and_no_emcy_are_judged_from_the_reports_and_the_trace() {
        let scenario = emulated_scenario("repetition-double-reception.toml");
        let on = status(true, 1, Cause::None);
        let mut observed = Observed {
            start: 5.0,
            applied: vec![5.21],
            statuses: vec![("node33a".into(), 4.9, on), ("node33b".into(), 4.9, on)],
            frames: Vec::new(),
            end: 5.8,
            events: event_log(4.0, 5.8, None, ""),
            judged_from: 0.0,
        };
        let report = emulated::judge(&scenario, &observed);
        assert!(report.passed(), "{}", report.text(&scenario));
        observed.statuses.push((
            "node33b".into(),
            5.3,
            status(false, 0, Cause::PlainRepeated),
        ));
        let emcy = shared::CanFrame::new(shared::CanId::new(0x081).unwrap(), &[0, 0x82]).unwrap();
        observed.frames.push((5.31, emcy));
        let report = emulated::judge(&scenario, &observed);
        let measured: Vec<&str> = report.checks.iter().map(|c| c.measured.as_str()).collect();
        assert_eq!(
            measured,
            [
                "0x01",
                "channel B left the working state at 300.000 ms (plain frame repeated with other data)",
                "0x00",
                "1 EMCY, the first at 310.000 ms: [00, 82]",
                "no output unjustified",
            ]
        );
    }

    /// Beside the file's bounds, the campaigns' oracle judges the emulated run from the hub's
    /// event log: node 33's output on after a well-formed pair from another sender (the
    /// hub's `insert`: 101h#03, 102h#FCh) carrying a bit node 1 never sent fails the run,
    /// at the instant and why, with the frames' senders in the timeline, although the
    /// file's expectations hold; a finding before the scenario (`judged_from`) is the one
    /// before's. A run without an event log is not passed for want of one.
    #[test]
    fn the_oracle_fails_an_emulated_run_whose_output_follows_a_foreign_pair() {
        let scenario = emulated_scenario("masquerade-well-formed-pair.toml");
        let on = status(true, 1, Cause::None);
        let gfc = status(false, 0, Cause::Gfc);
        let foreign = "frame t=5.200000 from=hub 101#03\nframe t=5.200300 from=hub 102#FC\n\
                       output t=5.210000 node33a 3\noutput t=5.210000 node33b 3\n\
                       frame t=5.260000 from=node1a 001#\n\
                       output t=5.270000 node33a 0\noutput t=5.270000 node33b 0\n";
        let mut observed = Observed {
            start: 5.0,
            applied: vec![5.199, 5.1995],
            statuses: vec![
                ("node33a".into(), 4.9, on),
                ("node33b".into(), 4.9, on),
                ("node33a".into(), 5.27, gfc),
                ("node33b".into(), 5.27, gfc),
            ],
            frames: Vec::new(),
            end: 5.6,
            events: event_log(4.0, 5.15, None, foreign),
            judged_from: 0.0,
        };
        let report = emulated::judge(&scenario, &observed);
        let text = report.text(&scenario);
        assert!(!report.passed(), "{text}");
        let oracle = report.checks.last().expect("the oracle's check");
        assert!(
            report.checks[..report.checks.len() - 1]
                .iter()
                .all(|check| check.passed),
            "the file's own bounds hold: {text}"
        );
        assert_eq!(oracle.line, 0);
        assert!(
            oracle
                .measured
                .starts_with("1 unjustified output(s), the first at 210.000 ms: output 0x3"),
            "{}",
            oracle.measured
        );
        let timeline = report.timeline.as_deref().expect("a timeline");
        assert!(timeline.contains("101 [1] [03] from hub"), "{timeline}");
        assert!(timeline.contains("output  node33b: 3"), "{timeline}");

        observed.judged_from = 5.3;
        assert!(emulated::judge(&scenario, &observed).passed());

        observed.events.clear();
        let report = emulated::judge(&scenario, &observed);
        assert_eq!(
            report.checks.last().map(|check| check.measured.as_str()),
            Some("no event log: nothing was judged")
        );
        assert!(!report.passed());
    }

    /// Each step is the hub's control command (`hub/src/control.rs`); NMT and GFC are
    /// frames the hub puts on the bus.
    #[test]
    fn each_step_is_the_hubs_control_command() {
        let text = |stimulus: Stimulus| -> Vec<String> {
            emulated::commands(&stimulus)
                .expect("the hub's")
                .iter()
                .map(ToString::to_string)
                .collect()
        };
        use shared::canopen::nmt::NmtCommand;
        assert_eq!(
            text(Stimulus::Nmt {
                command: NmtCommand::Stop,
                node: 1
            }),
            ["insert 0x000 02 01"]
        );
        assert_eq!(text(Stimulus::Gfc), ["insert 0x001"]);
        assert_eq!(
            text(Stimulus::Input {
                node: 1,
                channel: None,
                value: 0
            }),
            ["input node1a 0", "input node1b 0"]
        );
        assert_eq!(
            text(Stimulus::Fault(FaultSpec::Delay {
                id: 0x102,
                by_us: 150_000
            })),
            ["delay 0x102 150"]
        );
        assert_eq!(
            text(Stimulus::Fault(FaultSpec::Mute {
                node: 1,
                channel: Channel::A
            })),
            ["mute node1a"]
        );
        assert_eq!(
            text(Stimulus::Fault(FaultSpec::Cut { node: 33 })),
            ["cut node33-link"]
        );
        let refused = emulated::commands(&Stimulus::Fault(FaultSpec::NoInverted { node: 1 }));
        assert!(refused.unwrap_err().contains("the hub cannot inject"));
    }

    /// A host scenario (other network, or a host-only fault) is refused for the emulated
    /// network in a sentence, before anything runs.
    #[test]
    fn a_scenario_for_another_network_or_with_host_only_faults_is_refused() {
        let emulated_network = emulated_scenario("gfc-from-the-tool.toml").network;
        let host = file::load(&dir().join("gfc-from-the-tool.toml")).expect("parses");
        let why = emulated::check_playable(&host, &emulated_network, 500_000).unwrap_err();
        assert!(why.contains("is not the emulated network's"), "{why}");
        let mut host_only = emulated_scenario("gfc-from-the-tool.toml");
        host_only.steps[0].stimulus = Stimulus::Fault(FaultSpec::Clock {
            node: 33,
            channel: Channel::A,
            percent: 5,
        });
        let why = emulated::check_playable(&host_only, &emulated_network, 500_000).unwrap_err();
        assert!(
            why.contains("gfc-from-the-tool.toml:15: the fault `clock`"),
            "{why}"
        );
        let why = emulated::check_playable(
            &emulated_scenario("gfc-from-the-tool.toml"),
            &emulated_network,
            250_000,
        )
        .unwrap_err();
        assert!(why.contains("the emulated bus at 250 kbit/s"), "{why}");
    }

    /// The emulated scenarios run on the host simulation too (the same network file, with
    /// the emulated timing): there the bounds, which carry the emulation's margin, hold by far.
    #[test]
    fn every_emulated_scenario_file_passes_on_the_host_simulation_too() {
        let files = system_tests::scenario_runner::files_in(&dir().join("emulated")).unwrap();
        assert!(files.len() >= 10, "{} emulated scenarios", files.len());
        for path in &files {
            let scenario = file::load(path).unwrap_or_else(|error| panic!("{error}"));
            let report = system_tests::scenario_runner::run(&scenario).unwrap();
            assert!(report.passed(), "{}", report.text(&scenario));
        }
    }
}
