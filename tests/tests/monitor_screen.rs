//! `safety-config monitor` as a person sees it: in `tmux` at 120 × 40 against the host
//! simulation's nodes 1 and 33 behind `socketcand_sim` (the protocol core, configured and
//! started, in real time), the screen read with `capture-pane`: both nodes Operational, the
//! SRDO pair 101h/102h judged valid with its numbers; the monitor's `g` sends a GFC and the
//! nodes' EMCYs say in words why they went to the safe state; `q` ends the program with
//! success.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A child process killed when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A tmux session, killed when dropped.
struct Tmux(String);

impl Tmux {
    fn screen(&self) -> String {
        let output = Command::new("tmux")
            .args(["capture-pane", "-p", "-t", &self.0])
            .output()
            .expect("tmux capture-pane");
        String::from_utf8_lossy(&output.stdout).into_owned()
    }

    /// The screen once `seen` holds for it, or the last screen after `patience`.
    fn wait_for(&self, patience: Duration, seen: impl Fn(&str) -> bool) -> String {
        let until = Instant::now() + patience;
        loop {
            let screen = self.screen();
            if seen(&screen) || Instant::now() >= until {
                return screen;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    fn key(&self, key: &str) {
        let status = Command::new("tmux")
            .args(["send-keys", "-t", &self.0, key])
            .status()
            .expect("tmux send-keys");
        assert!(status.success());
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = Command::new("tmux")
            .args(["kill-session", "-t", &self.0])
            .status();
    }
}

/// The `safety-config` program, built when this test runs (it is another crate's binary).
fn safety_config() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let status = Command::new(env!("CARGO"))
        .args([
            "build",
            "--quiet",
            "-p",
            "safety-config",
            "--bin",
            "safety-config",
        ])
        .current_dir(&root)
        .status()
        .expect("cargo build");
    assert!(status.success(), "building safety-config failed");
    Path::new(env!("CARGO_BIN_EXE_socketcand_sim")).with_file_name("safety-config")
}

const NETWORK: &str = r#"
[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }
[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 100
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }
[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 500
srvt_ms = 100
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#;

#[test]
fn the_monitor_screen_shows_nodes_srdo_pairs_and_after_a_gfc_the_cause_in_words() {
    let program = safety_config();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|listener| listener.local_addr())
        .expect("a free port")
        .port();
    let _server = Killed(
        Command::new(env!("CARGO_BIN_EXE_socketcand_sim"))
            .arg(port.to_string())
            .spawn()
            .expect("socketcand_sim"),
    );
    let dir = std::env::temp_dir().join(format!("monitor-screen-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let network = dir.join("network.toml");
    std::fs::write(&network, NETWORK).unwrap();
    let exit = dir.join("exit");
    // socketcand_sim configures its nodes before it listens: retry until it does.
    let command = format!(
        "for try in $(seq 100); do {} --bus socketcand:127.0.0.1:{port}/can0 monitor {} && break; sleep 0.2; done; echo EXIT=$? > {}; sleep 60",
        program.display(),
        network.display(),
        exit.display()
    );
    let session = format!("monitor-screen-{}", std::process::id());
    let status = Command::new("tmux")
        .args([
            "new-session",
            "-d",
            "-s",
            &session,
            "-x",
            "120",
            "-y",
            "40",
            &command,
        ])
        .status()
        .expect("tmux is installed");
    assert!(status.success());
    let tmux = Tmux(session);

    let flowing = |screen: &str| {
        screen
            .lines()
            .any(|line| line.starts_with("1    emergency stop   Operational"))
            && screen
                .lines()
                .any(|line| line.starts_with("33   safe output      Operational"))
            && screen
                .lines()
                .any(|line| line.starts_with("101h/102h 1 → 33") && line.ends_with("valid"))
    };
    let screen = tmux.wait_for(Duration::from_secs(120), flowing);
    assert!(flowing(&screen), "the bus is not on the screen:\n{screen}");
    assert!(
        screen.starts_with("safety-config monitor: socketcand:127.0.0.1:"),
        "{screen}"
    );
    let srdo = screen
        .lines()
        .find(|line| line.starts_with("101h/102h"))
        .unwrap_or_default();
    assert!(
        srdo.contains(" / 100 ") && srdo.contains(" / 500 "),
        "{srdo}"
    );

    tmux.key("g");
    let safe = |screen: &str| {
        screen.contains("node 1: EMCY FF01h: GFC received: safe state")
            && screen.contains("node 33: EMCY FF01h: GFC received: safe state")
    };
    let screen = tmux.wait_for(Duration::from_secs(30), safe);
    assert!(safe(&screen), "no cause in words after the GFC:\n{screen}");
    assert!(
        screen.contains("GFC sent by this monitor (key g)"),
        "{screen}"
    );
    assert!(screen.contains("GFC: 1 (latest"), "{screen}");

    tmux.key("q");
    let until = Instant::now() + Duration::from_secs(30);
    while !exit.exists() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(100));
    }
    let code = std::fs::read_to_string(&exit).unwrap_or_default();
    assert_eq!(code.trim(), "EXIT=0", "{}", tmux.screen());
    let _ = std::fs::remove_dir_all(&dir);
}
