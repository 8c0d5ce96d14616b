//! The node's EDS (CiA 306): the committed file is the generated one, and it carries the
//! CANopen Safety keys of CiA 306 Annex A for every object of the device description.

use safety_config::eds;
use safety_device as device;

/// The committed EDS, as the repository holds it.
fn committed() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../eds/safety-node.eds");
    std::fs::read_to_string(path).expect("eds/safety-node.eds is committed")
}

/// CI's check: whoever changes the device description or the object dictionary regenerates
/// the EDS (`cargo run -p safety-config -- eds > eds/safety-node.eds`) in the same commit.
#[test]
fn cia306_the_committed_eds_is_the_generated_one() {
    let generated = eds::eds();
    let committed = committed();
    if generated != committed {
        let first = generated
            .lines()
            .zip(committed.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(generated.lines().count().min(committed.lines().count()));
        panic!(
            "eds/safety-node.eds differs from the generated EDS from line {}: regenerate it with \
             `cargo run -p safety-config -- eds > eds/safety-node.eds`",
            first + 1
        );
    }
}

/// CiA 306 Annex A: `CANopenSafetySupported=1`; `SRDOMapping=1` on exactly the objects the
/// device lets an SRDO map; `InvertedSRAD` on each plain object naming its inverted copy, on
/// no other.
#[test]
fn cia306_annex_a_safety_keys_follow_the_device_description() {
    let ini = ini::Ini::load_from_str(&eds::eds()).expect("the EDS is an INI file");
    assert_eq!(
        ini.get_from(Some("DeviceInfo"), "CANopenSafetySupported"),
        Some("1")
    );
    let mut mappable = 0;
    let mut linked = 0;
    for (section, properties) in ini.iter() {
        let Some(section) = section else { continue };
        if let Some(value) = properties.get("SRDOMapping") {
            assert_eq!(value, "1", "[{section}]");
            mappable += 1;
            let object = device::OBJECTS
                .iter()
                .find(|object| {
                    format!("{:04X}sub{:X}", object.address.index, object.address.sub) == section
                })
                .unwrap_or_else(|| {
                    panic!("[{section}] is SRDO-mappable but no application object")
                });
            let pair = device::INVERTED_PAIRS
                .iter()
                .find(|(plain, _)| *plain == object.address);
            match (properties.get("InvertedSRAD"), pair) {
                (Some(value), Some((_, inverted))) => {
                    assert_eq!(
                        value,
                        format!("0x{:04X}{:02X}", inverted.index, inverted.sub)
                    );
                    linked += 1;
                }
                (None, None) => {}
                (value, pair) => panic!("[{section}]: InvertedSRAD {value:?}, pair {pair:?}"),
            }
        } else {
            assert!(properties.get("InvertedSRAD").is_none(), "[{section}]");
        }
    }
    assert_eq!(mappable, device::OBJECTS.len());
    assert_eq!(linked, device::INVERTED_PAIRS.len());
}

/// The GFC parameter's entry says what this device does with it (the note on
/// `shared::safety::gfc::GFC_PARAMETER`): values above 1 are refused, and the file says
/// that 1 sends nothing.
#[test]
fn cia306_the_gfc_parameter_entry_carries_this_devices_meaning() {
    let ini = ini::Ini::load_from_str(&eds::eds()).expect("the EDS is an INI file");
    let entry = ini.section(Some("1300")).expect("[1300]");
    assert_eq!(entry.get("AccessType"), Some("rw"));
    assert_eq!(entry.get("HighLimit"), Some("1"));
    let comments = ini.section(Some("Comments")).expect("[Comments]");
    assert!(
        comments
            .iter()
            .any(|(_, line)| line.contains("1300h") && line.contains("no GFC is sent")),
        "{comments:?}"
    );
}

/// `safety-config eds` prints the committed EDS (the command CI's check tells a person to run).
#[test]
fn cia306_the_eds_command_prints_the_committed_eds() {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .arg("eds")
        .output()
        .expect("the program runs");
    assert!(output.status.success());
    assert!(String::from_utf8_lossy(&output.stdout) == committed());
}

/// Output piped into a program that stops reading ends the program quietly, the way it ends
/// any Unix tool (SIGPIPE), never with a panic's message on the terminal.
#[test]
fn output_into_a_closed_pipe_ends_without_a_panic() {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .arg("eds")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the program runs");
    // The reading end closed before the program writes its first line.
    drop(child.stdout.take());
    let output = child.wait_with_output().expect("the program ends");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
}
