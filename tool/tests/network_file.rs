//! Every class of network-file error comes back with its line, column and a sentence.

use safety_config::network_file::{FileError, parse};

const GOOD: &str = r#"[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, serial = 1 }

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 25
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]
"#;

/// `GOOD` with `from` replaced by `to`, parsed; the error it must give.
fn error(from: &str, to: &str) -> FileError {
    assert!(GOOD.contains(from), "{from}");
    parse(&GOOD.replace(from, to), "net.toml").expect_err(to)
}

fn assert_at(error: &FileError, line: usize, column: usize, words: &str) {
    assert_eq!((error.line, error.column), (line, column), "{error}");
    assert!(error.message.contains(words), "{error}");
    assert!(
        error
            .to_string()
            .starts_with(&format!("net.toml:{line}:{column}: ")),
        "{error}"
    );
}

#[test]
fn a_good_file_parses() {
    let network = parse(GOOD, "net.toml").unwrap();
    let srdo = &network.nodes[0].srdos[0].settings;
    assert_eq!(srdo.mapping, vec![0x6000_0108, 0x6001_0108]);
    assert_eq!(srdo.srvt, 20, "Table 5 default for a transmit SRDO");
}

#[test]
fn toml_syntax_error() {
    assert_at(&error("id = 1", "id = = 1"), 2, 6, "");
}

#[test]
fn unknown_field() {
    assert_at(
        &error("id = 1", "id = 1\nnode_id = 2"),
        3,
        1,
        "unknown field",
    );
}

#[test]
fn missing_field() {
    let e = error(
        "identity = { vendor = 0xABC, product = 0x304, serial = 1 }\n",
        "",
    );
    assert!(e.message.contains("missing field `identity`"), "{e}");
    assert_eq!(e.line, 1, "{e}");
}

#[test]
fn wrong_type() {
    assert_at(
        &error("refresh_time_ms = 25", "refresh_time_ms = \"25\""),
        8,
        19,
        "",
    );
}

#[test]
fn no_node() {
    let e = parse("[bus]\nsdo_timeout_ms = 100\n", "net.toml").unwrap_err();
    assert!(e.message.contains("names no node"), "{e}");
}

#[test]
fn node_id_out_of_range() {
    assert_at(
        &error("id = 1", "id = 128"),
        2,
        6,
        "the node-ID is 128, but must be 1 to 127",
    );
}

#[test]
fn duplicate_node_id() {
    let text = format!("{GOOD}\n{GOOD}");
    let e = parse(&text, "net.toml").unwrap_err();
    assert_at(&e, 13, 6, "node-ID 1 is given to two nodes");
}

#[test]
fn identity_out_of_range() {
    assert_at(
        &error("serial = 1", "serial = -1"),
        3,
        56,
        "the serial number is -1",
    );
}

#[test]
fn srdo_number_out_of_range() {
    assert_at(
        &error("number = 1", "number = 65"),
        6,
        10,
        "the SRDO number is 65, but must be 1 to 64",
    );
}

#[test]
fn duplicate_srdo() {
    let srdo = &GOOD[GOOD.find("[[node.srdo]]").unwrap()..];
    let text = format!("{GOOD}\n{}", srdo.replace("0x101, 0x102", "0x103, 0x104"));
    assert_at(
        &parse(&text, "net.toml").unwrap_err(),
        13,
        10,
        "SRDO 1 is listed twice",
    );
}

#[test]
fn shared_cob_ids() {
    let srdo = &GOOD[GOOD.find("[[node.srdo]]").unwrap()..];
    let text = format!("{GOOD}\n{}", srdo.replace("number = 1", "number = 2"));
    assert_at(
        &parse(&text, "net.toml").unwrap_err(),
        16,
        11,
        "SRDO 2 uses the COB-IDs of SRDO 1",
    );
}

#[test]
fn bad_direction() {
    assert_at(
        &error("\"transmit\"", "\"send\""),
        7,
        13,
        "must be \"transmit\" or \"receive\"",
    );
}

#[test]
fn time_for_the_other_direction() {
    assert_at(
        &error("refresh_time_ms = 25", "sct_ms = 25"),
        8,
        10,
        "give refresh_time_ms, not sct_ms",
    );
}

#[test]
fn missing_time() {
    assert_at(
        &error("refresh_time_ms = 25\n", ""),
        6,
        10,
        "refresh_time_ms is missing",
    );
}

#[test]
fn zero_refresh_time() {
    assert_at(
        &error("refresh_time_ms = 25", "refresh_time_ms = 0"),
        8,
        19,
        "must be 1 to 65535",
    );
}

#[test]
fn receive_needs_srvt_shorter_than_sct() {
    let receive = GOOD
        .replace("\"transmit\"", "\"receive\"")
        .replace("refresh_time_ms = 25", "sct_ms = 20\nsrvt_ms = 20")
        .replace(
            "[\"input\", \"input_inverted\"]",
            "[\"output\", \"output_inverted\"]",
        );
    assert_at(
        &parse(&receive, "net.toml").unwrap_err(),
        9,
        11,
        "the SRVT (20 ms) must be shorter than the SCT (20 ms)",
    );
    let no_srvt = receive.replace("srvt_ms = 20\n", "");
    assert_at(
        &parse(&no_srvt, "net.toml").unwrap_err(),
        6,
        10,
        "srvt_ms is missing",
    );
}

#[test]
fn cob_id_rules() {
    assert_at(
        &error("[0x101, 0x102]", "[0x101]"),
        9,
        11,
        "needs two identifiers",
    );
    assert_at(
        &error("[0x101, 0x102]", "[0x102, 0x103]"),
        9,
        11,
        "the first COB-ID must be odd",
    );
    assert_at(
        &error("[0x101, 0x102]", "[0x101, 0x104]"),
        9,
        11,
        "the first plus one",
    );
    assert_at(
        &error("[0x101, 0x102]", "[0x0FF, 0x100]"),
        9,
        11,
        "start at 101h",
    );
    assert_at(
        &error("[0x101, 0x102]", "[0x101, 0x800]"),
        9,
        19,
        "COB-ID 2 is 2048",
    );
}

#[test]
fn mapping_count() {
    assert_at(
        &error("[\"input\", \"input_inverted\"]", "[\"input\"]"),
        10,
        11,
        "needs 2 to 16, in pairs",
    );
}

#[test]
fn mapping_unknown_name_or_syntax() {
    assert_at(
        &error("\"input\",", "\"inptu\","),
        10,
        12,
        "neither an object name (input, input_inverted, output, output_inverted)",
    );
    assert_at(
        &error("\"input\",", "\"0x6000:1:x\","),
        10,
        12,
        "is not index:sub:bits",
    );
}

#[test]
fn mapping_wrong_direction_or_object() {
    assert_at(
        &error("\"input\",", "\"output\","),
        10,
        12,
        "cannot be mapped into a transmit SRDO or a produced SC-ID",
    );
    assert_at(
        &error("\"input\",", "\"0x6100:1:8\","),
        10,
        12,
        "no mappable object 6100h:01h",
    );
    assert_at(
        &error("\"input\",", "\"0x6000:1:16\","),
        10,
        12,
        "has 8 bits, not 16",
    );
}

#[test]
fn sdo_timeout_out_of_range() {
    let text = format!("[bus]\nsdo_timeout_ms = 0\n{GOOD}");
    assert_at(
        &parse(&text, "net.toml").unwrap_err(),
        2,
        18,
        "the SDO timeout (ms) is 0",
    );
}
