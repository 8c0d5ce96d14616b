//! Tests of the traceability matrix: reading clauses from test names, loading requirements,
//! reading the JUnit report, and the gate's failure cases on small fixtures.

use super::*;

fn requirement(id: &str) -> Named {
    Named::Requirement(id.to_owned())
}

#[test]
fn clauses_are_read_from_test_names() {
    let cases: [(&str, &[Named]); 10] = [
        (
            "en50325_5_7_1_2_srvt_event",
            &[requirement("EN 50325-5 7.1.2")],
        ),
        (
            "cia304_9_5_a_sends_the_plain_frame_only",
            &[requirement("CiA 304 9.5")],
        ),
        (
            "cia301_7_2_4_3_17_invalid_commands_abort",
            &[requirement("CiA 301 7.2.4.3.17")],
        ),
        (
            "cia301_table2_no_emcy_in_stopped",
            &[requirement("CiA 301 Table 2")],
        ),
        (
            "en50325_5_table9_golden_values",
            &[requirement("EN 50325-5 Table 9")],
        ),
        ("sc_req_05_outputs_zero", &[requirement("SC_REQ_05")]),
        (
            "iec61784_3_loss_of_the_inverted_frame",
            &[requirement("IEC 61784-3 loss")],
        ),
        (
            "iec61784_3_a_configuration_for_another_node",
            &[Named::StandardOnly("IEC 61784-3")],
        ),
        (
            "iso11898_1_duplicated_frames",
            &[Named::StandardOnly("ISO 11898-1")],
        ),
        ("poll_never_misses", &[]),
    ];
    for (name, expected) in cases {
        assert_eq!(named(name), expected, "{name}");
    }
}

#[test]
fn several_clauses_are_joined_by_and_but_and_in_the_words_is_not_a_clause() {
    assert_eq!(
        named("cia304_9_5_and_en50325_5_7_1_1_producer_sends_plain_then_inverted"),
        [requirement("CiA 304 9.5"), requirement("EN 50325-5 7.1.1")]
    );
    assert_eq!(
        named("cia301_7_2_8_3_1_addressed_and_broadcast_commands"),
        [requirement("CiA 301 7.2.8.3.1")]
    );
    // "table" followed by no number, and a prefix glued to a longer word, name nothing.
    assert_eq!(
        named("cia301_tables_are_sorted"),
        [Named::StandardOnly("CiA 301")]
    );
    assert_eq!(named("cia3011_something"), []);
    assert_eq!(named("sc_request_parsing"), []);
}

const GOOD: &str = r#"
[document]
title = "A standard"
source = "somewhere"

[[requirement]]
id = "EN 50325-5 7.1.2"
statement = "SCT and SRVT events give the safe state."
verification = "test"
applicability = ["device"]
implemented_in = ["shared::safety::srdo"]

[[requirement]]
id = "EN 50325-5 9.2"
statement = "Install per EN 61918."
verification = "review"
applicability = ["system-integrator"]
implemented_in = []
"#;

#[test]
fn requirements_load_with_the_line_of_each_entry() {
    let document = parse_file("requirements/a.toml", GOOD).unwrap();
    assert_eq!(document.title, "A standard");
    let lines: Vec<(&str, usize)> = document
        .requirements
        .iter()
        .map(|r| (r.id.as_str(), r.line))
        .collect();
    assert_eq!(lines, [("EN 50325-5 7.1.2", 6), ("EN 50325-5 9.2", 13)]);
    assert_eq!(document.requirements[0].status, Status::Implemented);
    assert!(document.requirements[0].needs_test());
    assert!(!document.requirements[1].needs_test());
}

/// The error for `text`, which must not load.
fn load_error(text: &str) -> String {
    format!(
        "{:#}",
        parse_file("requirements/bad.toml", text).unwrap_err()
    )
}

#[test]
fn a_bad_entry_is_refused_naming_its_file_and_line() {
    // A misspelt method: toml names the line and column.
    let error = load_error(&GOOD.replace("\"review\"", "\"reveiw\""));
    assert!(error.starts_with("requirements/bad.toml: "), "{error}");
    assert!(error.contains("line 16"), "{error}");
    assert!(error.contains("reveiw"), "{error}");
    // A field that is not in the schema: toml names its line.
    let error = load_error(&GOOD.replace("implemented_in = []", "implemented = []"));
    assert!(
        error.contains("line 18") && error.contains("unknown field `implemented`"),
        "{error}"
    );
    // The checks after parsing name the entry's first line.
    let error = load_error(&GOOD.replace(
        "applicability = [\"system-integrator\"]",
        "applicability = [\"not-applicable\"]",
    ));
    assert_eq!(
        error,
        "requirements/bad.toml:13: requirement `EN 50325-5 9.2`: a not-applicable requirement \
         needs its reason (`reason = \"…\"`)"
    );
    let error = load_error(&GOOD.replace("Install per EN 61918.", ""));
    assert!(error.starts_with("requirements/bad.toml:13: "), "{error}");
    let error = load_error(&GOOD.replace("[\"device\"]", "[]"));
    assert!(error.starts_with("requirements/bad.toml:6: "), "{error}");
}

#[test]
fn an_identifier_listed_twice_is_refused() {
    let dir = std::env::temp_dir().join(format!("xtask-trace-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("a.toml"), GOOD).unwrap();
    std::fs::write(dir.join("b.toml"), GOOD).unwrap();
    let error = format!("{:#}", load(&dir, &dir).unwrap_err());
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        error,
        "b.toml:6: requirement `EN 50325-5 7.1.2` is already listed at a.toml:6"
    );
}

#[test]
fn the_junit_report_gives_each_test_its_outcome() {
    let xml = r#"<?xml version="1.0" encoding="UTF-8"?>
<testsuites name="nextest-run" tests="3" failures="1">
  <testsuite name="shared" tests="3">
    <testcase name="node::tests::cia301_7_3_2_boot_up" classname="shared" time="0.01"/>
    <testcase name="sc_req_05_zero" classname="system-tests::dual_channel" time="0.5">
      <failure message="thread &apos;sc_req_05_zero&apos; panicked at x.rs:1:2" type="test failure">long text</failure>
    </testcase>
    <testcase name="slow" classname="shared"><skipped/></testcase>
  </testsuite>
</testsuites>"#;
    let tests = parse_junit(xml).unwrap();
    // In binary and path order, whatever order they finished in.
    let shown: Vec<String> = tests.iter().map(TestCase::shown).collect();
    assert_eq!(
        shown,
        [
            "shared node::tests::cia301_7_3_2_boot_up",
            "shared slow",
            "system-tests::dual_channel sc_req_05_zero"
        ]
    );
    assert_eq!(tests[0].function(), "cia301_7_3_2_boot_up");
    assert_eq!(tests[0].outcome, Outcome::Passed);
    assert_eq!(tests[1].outcome, Outcome::Skipped);
    assert_eq!(
        tests[2].outcome,
        Outcome::Failed("thread 'sc_req_05_zero' panicked at x.rs:1:2".to_owned())
    );
}

/// The fixture's requirements: one verified by name, one by listing, one planned, one by review.
const FIXTURE: &str = r#"
[document]
title = "Fixture"
source = "here"

[[requirement]]
id = "EN 50325-5 7.1.2"
statement = "Timing."
verification = "test"
applicability = ["device"]
implemented_in = []

[[requirement]]
id = "CiA 304 9.5 rule 1"
statement = "First transmission delayed."
verification = "test"
applicability = ["device"]
implemented_in = []
tests = ["delay_is_half_a_millisecond_per_node_id"]

[[requirement]]
id = "SC_REQ_18"
title = "SR data transmission"
statement = "Slots."
verification = "test"
applicability = ["device"]
status = "planned"
implemented_in = []

[[requirement]]
id = "EN 50325-5 9.6"
statement = "Safety manual."
verification = "review"
applicability = ["device"]
implemented_in = []
"#;

fn test(binary: &str, path: &str, outcome: Outcome) -> TestCase {
    TestCase {
        binary: binary.to_owned(),
        path: path.to_owned(),
        outcome,
    }
}

fn passing_run() -> Vec<TestCase> {
    vec![
        test(
            "shared",
            "srdo::tests::en50325_5_7_1_2_srvt_event",
            Outcome::Passed,
        ),
        test(
            "shared",
            "srdo::tests::delay_is_half_a_millisecond_per_node_id",
            Outcome::Passed,
        ),
        test("shared", "frame::tests::round_trip", Outcome::Passed),
    ]
}

#[test]
fn a_complete_passing_run_has_no_problems_and_lists_the_planned_requirement() {
    let documents = [parse_file("fixture.toml", FIXTURE).unwrap()];
    let tests = passing_run();
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(matrix.problems, Vec::<String>::new());
    let verdicts: Vec<Verdict> = documents[0]
        .requirements
        .iter()
        .map(|r| matrix.verdict(r))
        .collect();
    assert_eq!(
        verdicts,
        [
            Verdict::Pass,
            Verdict::Pass,
            Verdict::NotYetImplemented,
            Verdict::ByReview
        ]
    );
    assert_eq!(matrix.untraced, [2]);
    let md = report::markdown(&matrix);
    assert!(md.contains("### SC_REQ_18: SR data transmission"), "{md}");
    assert!(md.contains("- **status: NOT YET IMPLEMENTED**"), "{md}");
    assert!(md.contains("None: the gate passes."), "{md}");
    let html = report::html(&matrix);
    assert!(
        html.contains("<td class=\"pass\"><b>PASS</b></td>"),
        "{html}"
    );
}

#[test]
fn a_requirement_to_be_verified_by_test_without_a_test_fails_the_gate() {
    let documents = [parse_file("fixture.toml", FIXTURE).unwrap()];
    let mut tests = passing_run();
    tests.remove(0);
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(
        matrix.problems,
        [
            "Requirement `EN 50325-5 7.1.2` (fixture.toml:6) is to be verified by test, but no \
          test verifies it: name a test after it, list one under `tests`, or mark it \
          `status = \"planned\"`."
        ]
    );
    assert_eq!(
        matrix.verdict(&documents[0].requirements[0]),
        Verdict::NoTest
    );
    // A listed test that is not in the run is a problem of its own.
    let mut tests = passing_run();
    tests.remove(1);
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(
        matrix.problems,
        [
            "Requirement `CiA 304 9.5 rule 1` (fixture.toml:13) lists test \
             `delay_is_half_a_millisecond_per_node_id`, which is not among the tests that ran.",
            "Requirement `CiA 304 9.5 rule 1` (fixture.toml:13) is to be verified by test, but \
             no test verifies it: name a test after it, list one under `tests`, or mark it \
             `status = \"planned\"`."
        ]
    );
    // Tests that were all skipped are no verification either.
    let mut tests = passing_run();
    tests[0].outcome = Outcome::Skipped;
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(
        matrix.problems,
        [
            "Requirement `EN 50325-5 7.1.2` (fixture.toml:6) is to be verified by test, but none \
          of its tests ran."
        ]
    );
}

#[test]
fn a_test_naming_an_unknown_requirement_fails_the_gate() {
    let documents = [parse_file("fixture.toml", FIXTURE).unwrap()];
    let mut tests = passing_run();
    tests.push(test(
        "shared",
        "x::en50325_5_7_1_9_no_such_clause",
        Outcome::Passed,
    ));
    tests.push(test(
        "shared",
        "x::cia301_no_clause_at_all",
        Outcome::Passed,
    ));
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(
        matrix.problems,
        [
            "Test `shared x::en50325_5_7_1_9_no_such_clause` names requirement \
             `EN 50325-5 7.1.9`, which no requirements file lists: add it to requirements/ or \
             correct the name.",
            "Test `shared x::cia301_no_clause_at_all` names CiA 301 but no clause, and no \
             requirement lists it under `tests`: name the clause or list the test."
        ]
    );
}

#[test]
fn a_failing_test_fails_the_gate_and_its_requirement() {
    let documents = [parse_file("fixture.toml", FIXTURE).unwrap()];
    let mut tests = passing_run();
    tests[0].outcome = Outcome::Failed("assertion failed at srdo.rs:10:5".to_owned());
    // A failing test that verifies no requirement fails the gate too.
    tests[2].outcome = Outcome::Failed("panicked".to_owned());
    let matrix = Matrix::build(&documents, &tests);
    assert_eq!(
        matrix.problems,
        [
            "Test `shared srdo::tests::en50325_5_7_1_2_srvt_event` failed: assertion failed at \
             srdo.rs:10:5",
            "Test `shared frame::tests::round_trip` failed: panicked"
        ]
    );
    assert_eq!(matrix.verdict(&documents[0].requirements[0]), Verdict::Fail);
    let md = report::markdown(&matrix);
    assert!(
        md.contains("FAIL `en50325_5_7_1_2_srvt_event` (shared)"),
        "{md}"
    );
    assert!(md.contains("- **status: FAIL**"), "{md}");
}
