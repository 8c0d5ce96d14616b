//! `cargo xtask emulate`: the emulated safety network (first slice of the emulated-network
//! issue). The bus hub, four QEMU instances (node 1: emergency-stop input device, node 33:
//! safe output device, each channel A and channel B with their link), and a configuration tool
//! on the hub's TCP port that configures, signs, validates, stores and starts the nodes, then
//! watches the bus.
//!
//! Every child process is killed when the task ends, whichever way it ends.

use crate::qemu;
use crate::toolchain;
use anyhow::{Context, Result, bail};
use can_hub::tool::Tool;
use shared::canopen::nmt::NmtCommand;
use shared::canopen::od::Address;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// Child processes, killed on drop.
struct Children(Vec<(String, Child)>);

impl Drop for Children {
    fn drop(&mut self) {
        for (_, child) in &mut self.0 {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

const HUB_TCP: &str = "127.0.0.1:29536";

fn qemu_instance(
    image: &Path,
    node: u8,
    can: &Path,
    link: &Path,
    server: bool,
    log: &Path,
) -> Result<Child> {
    let link_spec = format!(
        "socket,id=link,path={}{}",
        link.display(),
        if server { ",server=on,wait=off" } else { "" }
    );
    Command::new("qemu-system-arm")
        .args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"])
        .args([
            "-semihosting-config",
            &format!("enable=on,target=native,arg=node={node}"),
        ])
        .args(["-chardev", &format!("socket,id=can,path={}", can.display())])
        .args(["-chardev", &link_spec])
        .args([
            "-serial",
            "null",
            "-serial",
            "chardev:can",
            "-serial",
            "chardev:link",
        ])
        .arg("-kernel")
        .arg(image)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(log)?)
        .stderr(std::fs::File::create(log.with_extension("err"))?)
        .spawn()
        .context("starting qemu-system-arm")
}

/// `cargo xtask emulate`.
pub fn run(root: &Path, seconds: u64) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_qemu()?;
    toolchain::ensure_defmt_print()?;
    qemu::build(root, &cross)?;
    crate::run(crate::cargo().args(["build", "--quiet", "-p", "can-hub"]))?;
    let dir: PathBuf = root.join("target/emulate");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let socket = |name: &str| dir.join(format!("{name}.sock"));

    let mut children = Children(Vec::new());
    let hub = Command::new(root.join("target/debug/can-hub"))
        .args(["--tcp", HUB_TCP])
        .args(["--socket"])
        .arg(socket("node1a"))
        .args(["--socket"])
        .arg(socket("node1b"))
        .args(["--socket"])
        .arg(socket("node33a"))
        .args(["--socket"])
        .arg(socket("node33b"))
        .arg("--candump")
        .arg(dir.join("bus.log"))
        .arg("--pcap")
        .arg(dir.join("bus.pcap"))
        .spawn()
        .context("starting can-hub")?;
    children.0.push(("hub".into(), hub));
    // The tool joins first, so it sees the boot-up messages.
    let mut tool = Tool::connect(HUB_TCP, Duration::from_secs(5))?;
    for (node, name) in [(1u8, "node1"), (33, "node33")] {
        for (channel, server) in [("a", true), ("b", false)] {
            if !server {
                std::thread::sleep(Duration::from_millis(200));
            }
            let image = qemu::image(&cross, root, channel);
            let child = qemu_instance(
                &image,
                node,
                &socket(&format!("{name}{channel}")),
                &socket(&format!("{name}-link")),
                server,
                &dir.join(format!("{name}{channel}.defmt")),
            )?;
            children.0.push((format!("{name}{channel}"), child));
        }
    }

    eprintln!("xtask: waiting for the boot-up or heartbeat messages of nodes 1 and 33");
    let mut booted = [false; 2];
    let _ = tool.receive_until(Duration::from_secs(20), |frame| {
        match frame.id().raw() {
            0x701 => booted[0] = true,
            0x721 => booted[1] = true,
            _ => {}
        }
        booted == [true, true]
    })?;
    if booted != [true, true] {
        bail!("no boot-up from node 1 and node 33 within 20 s (booted: {booted:?})");
    }
    eprintln!("xtask: configuring over SDO: node 33 consumes node 1's SRDO (0x101/0x102)");
    let configure = |tool: &mut Tool| -> Result<(), shared::canopen::sdo_client::ClientError> {
        tool.write(33, Address::new(0x1301, 1), &[0])?;
        tool.write(33, Address::new(0x1301, 5), &0x101u32.to_le_bytes())?;
        tool.write(33, Address::new(0x1301, 6), &0x102u32.to_le_bytes())?;
        // Emulation timing: refresh 100 ms, SCT 500 ms, SRVT 100 ms (QEMU's scheduling on a
        // shared host is coarser than an MCU's).
        tool.write(33, Address::new(0x1301, 2), &500u16.to_le_bytes())?;
        tool.write(33, Address::new(0x1301, 3), &[100])?;
        tool.write(33, Address::new(0x1301, 1), &[2])?;
        tool.write(1, Address::new(0x1301, 2), &100u16.to_le_bytes())?;
        for id in [1, 33] {
            let signature = tool.sign_validate_store(id)?;
            eprintln!("xtask: node {id}: SRDO 1 signature {signature:04X}h, validated, stored");
        }
        Ok(())
    };
    configure(&mut tool).map_err(|error| anyhow::anyhow!("configuration refused: {error:?}"))?;
    tool.nmt(NmtCommand::Start, 0)?;
    eprintln!("xtask: NMT start sent; watching the bus for {seconds} s");
    tool.seen.clear();
    tool.listen(Duration::from_secs(seconds))?;

    let count = |id: u16| tool.seen.iter().filter(|(_, f)| f.id().raw() == id).count();
    let last_state = |id: u16| {
        tool.seen
            .iter()
            .rev()
            .find(|(_, f)| f.id().raw() == id)
            .and_then(|(_, f)| f.data().first().copied())
    };
    let emcys: Vec<String> = tool
        .seen
        .iter()
        .filter(|(_, f)| (0x081..=0x0FF).contains(&f.id().raw()))
        .map(|(_, f)| format!("{:03X}#{:02X?}", f.id().raw(), f.data()))
        .collect();
    println!("\n## Emulated network, {seconds} s after NMT start");
    println!(
        "   node 1  heartbeat state: {:?} (5 = Operational)",
        last_state(0x701)
    );
    println!(
        "   node 33 heartbeat state: {:?} (5 = Operational)",
        last_state(0x721)
    );
    println!(
        "   SRDO 1 plain frames (0x101, channel A of node 1): {}",
        count(0x101)
    );
    println!(
        "   SRDO 1 inverted frames (0x102, channel B of node 1): {}",
        count(0x102)
    );
    println!(
        "   EMCY: {}",
        if emcys.is_empty() {
            "none".into()
        } else {
            emcys.join(", ")
        }
    );
    println!(
        "   traces: {} and {}",
        dir.join("bus.log").display(),
        dir.join("bus.pcap").display()
    );
    drop(children);
    for name in ["node1a", "node1b", "node33a", "node33b"] {
        let image = qemu::image(&cross, root, &name[name.len() - 1..]);
        let raw = std::fs::read(dir.join(format!("{name}.defmt")))?;
        let decoded = decode(&image, &raw)?;
        std::fs::write(dir.join(format!("{name}.log")), &decoded)?;
        let faults: Vec<&str> = decoded.lines().filter(|l| l.contains("Fault(")).collect();
        println!(
            "   {name}: {}",
            if faults.is_empty() {
                "no channel fault".to_string()
            } else {
                faults.join("; ")
            }
        );
    }
    let operational = last_state(0x701) == Some(0x05) && last_state(0x721) == Some(0x05);
    if operational && count(0x101) > 0 && count(0x102) > 0 && emcys.is_empty() {
        println!("   every node Operational, SRDOs exchanged, no EMCY");
        Ok(())
    } else {
        bail!("the emulated network did not reach Operational with SRDOs flowing")
    }
}

fn decode(image: &Path, raw: &[u8]) -> Result<String> {
    use std::io::Write as _;
    let mut child = Command::new("defmt-print")
        .arg("-e")
        .arg(image)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()?;
    if let Some(mut stdin) = child.stdin.take() {
        stdin.write_all(raw)?;
    }
    Ok(String::from_utf8_lossy(&child.wait_with_output()?.stdout).into_owned())
}
