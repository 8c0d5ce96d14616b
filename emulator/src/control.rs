//! The emulated network's control port (`emulate-network --control ADDRESS:PORT`): the line
//! protocol of `can-hub`'s control port ([`can_hub::control`], its parser and its lines), so
//! that a program driving the network (`cargo xtask run`) talks to it as it talked to the QEMU
//! network under the hub until 2026-12-07.
//!
//! - [`Panel`], sans-I/O: carries out a [`Command`] on the [`Network`] (a contact of a
//!   channel, the bus faults of the hub's vocabulary on the same bus model, a link wire cut
//!   and mended, a frame from the port itself), and keeps every channel's status as the
//!   network shows it from outside, as a test rig around real boards reads it: the node's
//!   heartbeats (its NMT state; a boot-up clears what was latched), its EMCY frames (the
//!   cause), the channel's own log (a `SafeState(..)` or `Fault(..)` line and the cause it
//!   names), its output pin, the contact as driven, the link wire as cut, the SRDO frames it
//!   sent (SRDO frames, SimpleCAN data packets), and the SRDO pairs and SimpleCAN data packets
//!   the bus delivered to it while Operational and working, once its
//!   output has come on since its node's boot-up (a consumer's output comes on only on
//!   confirmed pairs; a producer's never does). That count is what reached a working
//!   consumer, not the channel's own count of the pairs it validated. The figures the QEMU
//!   images measured themselves are measured here from outside ([`crate::observed`], in
//!   virtual time, [`Panel::measure`]): the longest gap between two link messages reaching
//!   the channel, the longest wake-up of its core (to its next sleep, interrupts included),
//!   its deepest stack (the stack pointer at every translated block's start, followed from
//!   the panel's start). No stall is reported: every MCU runs in the one lockstep virtual
//!   time, nothing stops one while the others run on (0). Nor are discarded frames, which
//!   only the channel's own count knows (0).
//! - [`Server`]: the port on TCP ([`can_hub::port::accept_control`], the bounds of the hub's
//!   port), the answers and the status lines written to every client.
//!
//! A line that is not a command, or a command the network cannot carry out, is answered
//! `error <why>` in a sentence and nothing is changed.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::net::{TcpListener, TcpStream};
use std::sync::mpsc::{self, Receiver};

use can_hub::bus::{Fault, Injection, Match};
use can_hub::control::{Command, status_line};
use can_hub::port::ControlEvent;
use emulation_wire::Status;
use shared::canopen::emcy::{self, Emergency};
use shared::canopen::nmt::NmtState;
use shared::safety::cause::Cause;
use shared::simplecan::frame::{self as simplecan, SYNC_IDENTIFIER};
use shared::{CanFrame, CanId, Instant};

use crate::network::{Event, Network};
use crate::observed::status_ms;
use crate::time::Nanos;

/// How often every channel's status is reported when it does not change (virtual time); a
/// change is reported at once.
pub const REPORT_PERIOD: Nanos = 100_000_000;

/// The SRDO identifiers (CiA 304: 101h to 180h, plain frames odd, inverted frames even).
const SRDO_IDS: std::ops::RangeInclusive<u16> = 0x101..=0x180;

/// What is known of one channel (one MCU).
#[derive(Clone, Debug, Default)]
struct Channel {
    /// Its node-ID, from its name (`node33a`); `None` for an MCU that LSS configures.
    node: Option<u8>,
    /// The contact as last driven: 0 open, 1 closed.
    input: u8,
    /// Its link wire is cut.
    cut: bool,
    /// Its output pin is on.
    output: bool,
    /// Its output pin came on since its node's last boot-up: it consumes an SRDO.
    consumer: bool,
    /// Its log reported a safe state since the node's last boot-up.
    safe: bool,
    /// The cause its log named, when it named one.
    cause: Option<Cause>,
    sent: u16,
    validated: u16,
    /// The longest gap between two link messages it received, in milliseconds.
    link_gap_ms: u16,
    /// The longest wake-up of its core, in milliseconds.
    busy_ms: u16,
    /// Its deepest stack, in bytes.
    stack: u16,
}

/// What is known of one node from the bus.
#[derive(Clone, Copy, Debug, Default)]
struct Node {
    /// The state code of its latest heartbeat or boot-up message.
    nmt: u8,
    /// The cause of its latest EMCY since its last boot-up.
    cause: Option<Cause>,
}

/// The control port's commands carried out on a network, and every channel's status.
pub struct Panel {
    names: Vec<String>,
    channels: Vec<Channel>,
    nodes: BTreeMap<u8, Node>,
    /// The links between the channels of a node, as the hub names them (`node33-link`).
    links: Vec<(String, [usize; 2])>,
    /// The port's own participant on the bus (`insert`).
    own: usize,
    /// The latest plain SRDO frame on the bus, until its inverted half.
    plain: Option<u16>,
    /// What was last reported of each channel, and when.
    reported: Vec<Option<(Nanos, Status)>>,
}

/// `node33a` → 33.
fn node_of(name: &str) -> Option<u8> {
    name.strip_prefix("node")?
        .strip_suffix(['a', 'b'])?
        .parse()
        .ok()
}

/// The cause a log line names: the longest of [`Cause`]'s names that appears in it as a
/// word (`Srdo(SrdoFault { srdo: SrdoNumber(1), cause: SrvtElapsed })`, `SafeState(Gfc)`).
fn logged_cause(line: &str) -> Option<Cause> {
    let words: Vec<&str> = line
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|word| !word.is_empty())
        .collect();
    Cause::ALL
        .into_iter()
        .filter(|cause| *cause != Cause::None)
        .filter(|cause| {
            let name = format!("{cause:?}");
            words.contains(&name.as_str())
                || name
                    .strip_prefix("Integrity")
                    .is_some_and(|rest| line.contains(&format!("Integrity({rest}")))
        })
        .max_by_key(|cause| format!("{cause:?}").len())
}

impl Panel {
    /// The panel of `network`, whose contacts are all `input_closed` at power-on; the nodes'
    /// links are those of MCUs `2n` and `2n + 1` (as `emulate-network` wires them). Joins the
    /// bus as an external participant named `control`. Every MCU's stack is followed from now
    /// on ([`crate::cpu::Machine::follow_stack`]).
    pub fn new(network: &mut Network, input_closed: bool) -> Panel {
        let names: Vec<String> = network.names().map(str::to_owned).collect();
        let channels = names
            .iter()
            .map(|name| Channel {
                node: node_of(name),
                input: u8::from(input_closed),
                ..Channel::default()
            })
            .collect();
        let links = names
            .chunks(2)
            .enumerate()
            .filter(|(_, pair)| pair.len() == 2)
            .map(|(pair, names)| {
                let node = names[0].trim_end_matches(['a', 'b']);
                (format!("{node}-link"), [2 * pair, 2 * pair + 1])
            })
            .collect();
        for mcu in 0..names.len() {
            network.machine_mut(mcu).follow_stack();
        }
        let own = network.join_external("control");
        // It sends (`insert`) and never receives: nothing is kept for it.
        network.leave_external(own);
        Panel {
            reported: vec![None; names.len()],
            names,
            channels,
            nodes: BTreeMap::new(),
            links,
            own,
            plain: None,
        }
    }

    fn mcu(&self, name: &str) -> Result<usize, String> {
        self.names.iter().position(|n| n == name).ok_or_else(|| {
            format!(
                "no participant `{name}` (there are: {})",
                self.names.join(", ")
            )
        })
    }

    fn link(&self, name: &str) -> Result<[usize; 2], String> {
        self.links
            .iter()
            .find(|(link, _)| link == name)
            .map(|(_, ends)| *ends)
            .ok_or_else(|| {
                let names: Vec<&str> = self.links.iter().map(|(link, _)| link.as_str()).collect();
                format!("no link `{name}` (there are: {})", names.join(", "))
            })
    }

    /// Carries out `command` on `network` now; why not, in a sentence (and nothing changed).
    pub fn apply(&mut self, network: &mut Network, command: &Command) -> Result<(), String> {
        let now = Instant::from_micros(network.now() / 1_000);
        let next = |id| Match::next_with_id(id, now);
        let inject = |network: &mut Network, when, fault| {
            network.bus_mut().inject(Injection::new(when, fault));
        };
        match command {
            Command::Input { name, value } => {
                let mcu = self.mcu(name)?;
                if *value > 1 {
                    return Err(format!(
                        "`{name}`'s input is one contact: 0 (open) or 1 (closed), not {value}"
                    ));
                }
                network.set_input(mcu, *value == 1);
                self.channels[mcu].input = *value;
            }
            Command::Drop(id) => inject(network, next(*id), Fault::Drop),
            Command::Corrupt { id, byte, mask } => inject(
                network,
                next(*id),
                Fault::Corrupt {
                    byte: *byte,
                    mask: *mask,
                },
            ),
            Command::Delay { id, ms } => inject(
                network,
                next(*id),
                Fault::Delay(shared::Duration::from_millis(*ms)),
            ),
            Command::Repeat(id) => inject(network, next(*id), Fault::Repeat),
            Command::Reorder(id) => inject(network, next(*id), Fault::Reorder),
            Command::Insert { id, data } => {
                let frame = CanId::new(*id)
                    .ok()
                    .and_then(|id| CanFrame::new(id, data).ok())
                    .ok_or_else(|| format!("{command} is not a CAN frame"))?;
                if !network.has_room(self.own) {
                    return Err(format!(
                        "the control port's own transmit queue is full ({} frames waiting for \
                         the bus): {command} not sent",
                        can_hub::bus::TRANSMIT_QUEUE
                    ));
                }
                network.send(self.own, frame);
            }
            Command::Mute(name, true) => {
                let mcu = self.mcu(name)?;
                inject(network, Match::all_from(mcu, now), Fault::Mute);
            }
            Command::Mute(name, false) => {
                let mcu = self.mcu(name)?;
                network.bus_mut().retain_faults(|injection| {
                    !(injection.fault == Fault::Mute && injection.when.from == Some(mcu))
                });
            }
            Command::Cut(name) | Command::Restore(name) => {
                let cut = matches!(command, Command::Cut(_));
                for end in self.link(name)? {
                    network.cut_link(end, cut);
                    self.channels[end].cut = cut;
                }
            }
            Command::Clear => network.bus_mut().clear_faults(),
            Command::PowerCycle(names) => {
                let mcus = names
                    .iter()
                    .map(|name| self.mcu(name))
                    .collect::<Result<Vec<_>, _>>()?;
                // What a channel showed before is cleared by its node's boot-up message.
                network.power_cycle(&mcus);
            }
            Command::Load { .. } | Command::LoadOff => {
                return Err(
                    "the emulated network generates no load on its control port (`emulate-network \
                     --nominal --load PERCENT` runs the nominal case under load)"
                        .to_owned(),
                );
            }
        }
        Ok(())
    }

    /// The answer to one line from a client (as [`can_hub::control::read_line`] read it), the
    /// command carried out when it is one: `ok <command> t=<seconds>` or `error <why>`.
    pub fn answer(&mut self, network: &mut Network, line: Result<String, String>) -> String {
        match line
            .and_then(|line| Command::parse(&line))
            .and_then(|command| self.apply(network, &command).map(|()| command))
        {
            Ok(command) => format!("ok {command} t={:.6}", seconds(network.now())),
            Err(why) => format!("error {why}"),
        }
    }

    /// Takes in an event of the network.
    pub fn event(&mut self, event: &Event) {
        match event {
            Event::Output { mcu, on, .. } => {
                if let Some(channel) = self.channels.get_mut(*mcu) {
                    channel.output = *on;
                    channel.consumer |= *on;
                }
            }
            Event::Frame { from, frame, .. } => self.frame(from, frame),
            Event::Reset { .. }
            | Event::Stopped { .. }
            | Event::Refused { .. }
            | Event::BitRate { .. } => {}
        }
    }

    fn frame(&mut self, from: &str, frame: &CanFrame) {
        let id = frame.id().raw();
        let sender = self.names.iter().position(|name| name == from);
        if let (0x701..=0x77F, [state]) = (id, frame.data()) {
            let node = (id - 0x700) as u8;
            let known = self.nodes.entry(node).or_default();
            known.nmt = *state;
            if *state == 0 {
                // A boot-up: the node was reset or powered on, what was latched is gone.
                known.cause = None;
                for channel in &mut self.channels {
                    if channel.node == Some(node) {
                        channel.safe = false;
                        channel.cause = None;
                        channel.consumer = false;
                    }
                }
            }
        }
        if let Some((node, cause)) = crate::e2e::emcy_cause(frame) {
            self.nodes.entry(node).or_default().cause = Some(cause);
        } else if (0x081..=0x0FF).contains(&id)
            && Emergency::parse(frame.data()).is_some_and(|emcy| emcy.code == emcy::code::NO_ERROR)
        {
            // An error reset (CiA 301 7.2.7.3.1): the node says it has no error left.
            self.nodes.entry((id - 0x080) as u8).or_default().cause = None;
        }
        let simplecan_data = simplecan::is_simplecan(frame.id()) && id != SYNC_IDENTIFIER.raw();
        if (SRDO_IDS.contains(&id) || simplecan_data) && !frame.is_remote() {
            if let Some(sender) = sender {
                self.channels[sender].sent = self.channels[sender].sent.saturating_add(1);
            }
            // A value is complete with an SRDO's inverted half, or with a SimpleCAN data
            // packet (its CRC is the consumer's to check).
            let complete = if simplecan_data {
                true
            } else if id % 2 == 1 {
                self.plain = Some(id);
                false
            } else {
                self.plain.take() == Some(id - 1)
            };
            if complete {
                self.delivered(sender);
            }
        }
    }

    /// A complete value (an SRDO pair, a SimpleCAN data packet) from `sender` reached every
    /// other channel: counted for each working, Operational consumer.
    fn delivered(&mut self, sender: Option<usize>) {
        let receivers: Vec<usize> = (0..self.channels.len())
            .filter(|&mcu| Some(mcu) != sender && self.channels[mcu].consumer)
            .filter(|&mcu| {
                let status = self.status(mcu);
                status.working && status.nmt_state() == Some(NmtState::Operational)
            })
            .collect();
        for mcu in receivers {
            let channel = &mut self.channels[mcu];
            channel.validated = channel.validated.saturating_add(1);
        }
    }

    /// Takes in a line of MCU `mcu`'s decoded log.
    pub fn log(&mut self, mcu: usize, line: &str) {
        let Some(channel) = self.channels.get_mut(mcu) else {
            return;
        };
        if line.contains("SafeState(") || line.starts_with("Fault(") {
            channel.safe = true;
            if let Some(cause) = logged_cause(line) {
                channel.cause = Some(cause);
            }
        }
    }

    /// Takes in what `network` measured of every channel from outside so far: the longest
    /// link gap, the longest wake-up and the deepest stack ([`crate::observed`]); the status
    /// lines carry them from then on.
    pub fn measure(&mut self, network: &Network) {
        for (mcu, channel) in self.channels.iter_mut().enumerate() {
            let machine = network.machine(mcu);
            channel.link_gap_ms = status_ms(network.longest_link_gap(mcu));
            channel.busy_ms = status_ms(machine.longest_activation());
            channel.stack = machine
                .deepest_stack()
                .map_or(0, |bytes| u16::try_from(bytes).unwrap_or(u16::MAX));
        }
    }

    /// Channel `mcu`'s status as the network shows it.
    pub fn status(&self, mcu: usize) -> Status {
        let channel = &self.channels[mcu];
        let node = channel
            .node
            .and_then(|node| self.nodes.get(&node))
            .copied()
            .unwrap_or_default();
        let cause = channel.cause.or(node.cause);
        Status {
            nmt: node.nmt,
            working: !channel.safe && node.cause.is_none(),
            link_up: !channel.cut,
            output: u8::from(channel.output),
            input: channel.input,
            cause: cause.map_or(0, Cause::code),
            sent: channel.sent,
            validated: channel.validated,
            longest_stall_ms: 0,
            longest_link_gap_ms: channel.link_gap_ms,
            longest_busy_ms: channel.busy_ms,
            stack_used: channel.stack,
            discarded: 0,
        }
    }

    /// The status lines due at virtual time `now`: a channel's when what a watcher acts on
    /// changed, or when it was last reported [`REPORT_PERIOD`] ago (a measured figure that
    /// grew waits for the period, as the images' own reports do).
    pub fn reports(&mut self, now: Nanos) -> Vec<String> {
        let mut lines = Vec::new();
        for mcu in 0..self.names.len() {
            let status = self.status(mcu);
            let due = match self.reported[mcu] {
                None => true,
                Some((at, last)) => {
                    acted_on(&last) != acted_on(&status) || now >= at + REPORT_PERIOD
                }
            };
            if due {
                self.reported[mcu] = Some((now, status));
                lines.push(status_line(&self.names[mcu], seconds(now), &status));
            }
        }
        lines
    }

    /// Whether every channel of node `node` is Operational and working.
    pub fn working(&self, node: u8) -> bool {
        (0..self.names.len())
            .filter(|&mcu| self.channels[mcu].node == Some(node))
            .all(|mcu| {
                let status = self.status(mcu);
                status.working && status.nmt_state() == Some(NmtState::Operational)
            })
    }
}

/// `status` without the figures measured over time (the longest gaps, wake-ups and stack),
/// which a watcher reads but does not act on.
fn acted_on(status: &Status) -> Status {
    Status {
        longest_stall_ms: 0,
        longest_link_gap_ms: 0,
        longest_busy_ms: 0,
        stack_used: 0,
        ..*status
    }
}

/// Nanoseconds as seconds.
fn seconds(at: Nanos) -> f64 {
    at as f64 / 1e9
}

/// The control port on TCP: its clients' lines answered, the status lines written to all.
pub struct Server {
    events: Receiver<ControlEvent>,
    clients: BTreeMap<usize, TcpStream>,
    local: std::net::SocketAddr,
}

impl Server {
    /// Listens on `address` (`127.0.0.1:29537`).
    pub fn listen(address: &str) -> Result<Server, String> {
        let cannot = |error: std::io::Error| {
            format!("cannot listen for control clients on {address}: {error}")
        };
        let listener = TcpListener::bind(address).map_err(cannot)?;
        let local = listener.local_addr().map_err(cannot)?;
        let (tx, events) = mpsc::channel();
        can_hub::port::accept_control(listener, "the emulated network", move |event| {
            tx.send(event).is_ok()
        });
        Ok(Server {
            events,
            clients: BTreeMap::new(),
            local,
        })
    }

    /// The address it listens on (the port chosen, when asked for port 0).
    pub fn local_addr(&self) -> std::net::SocketAddr {
        self.local
    }

    /// Answers the lines that came since the last call, carrying out their commands on
    /// `network` now, in the order they came.
    pub fn serve(&mut self, panel: &mut Panel, network: &mut Network) {
        while let Ok(event) = self.events.try_recv() {
            match event {
                ControlEvent::Joined(client, stream) => {
                    self.clients.insert(client, stream);
                }
                ControlEvent::Line(client, line) => {
                    let answer = panel.answer(network, line);
                    self.write(Some(client), &answer);
                }
            }
        }
    }

    /// Writes `line` to client `to`, or to every client; a client that cannot be written to
    /// (gone, or not reading for [`can_hub::port::WRITE_TIMEOUT`]) is forgotten.
    pub fn write(&mut self, to: Option<usize>, line: &str) {
        let mut gone = Vec::new();
        for (&client, stream) in &mut self.clients {
            if to.is_some_and(|to| to != client) {
                continue;
            }
            if writeln!(stream, "{line}").is_err() {
                gone.push(client);
            }
        }
        for client in gone {
            self.clients.remove(&client);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A network of no MCU: the bus alone.
    fn bus_only() -> Network {
        Network::new(Vec::new(), 500_000).expect("a network of no MCU")
    }

    /// Lines that are not commands, or commands this network cannot carry out, are answered
    /// with a sentence naming what is wrong, and the next line is served as usual.
    #[test]
    fn bad_control_lines_are_answered_in_words() {
        let mut network = bus_only();
        let mut panel = Panel::new(&mut network, true);
        let mut answer = |line: &str| panel.answer(&mut network, Ok(line.to_owned()));
        for (line, words) in [
            ("explode", "is not a command"),
            ("", "empty command"),
            ("drop 0x800", "11-bit"),
            ("input node1a 0", "no participant `node1a`"),
            ("cut node33-link", "no link `node33-link`"),
            ("mute node9b", "no participant `node9b`"),
            ("power-cycle node9a", "no participant `node9a`"),
            ("power-cycle", "is not a command"),
            ("load 30 281#00", "generates no load"),
            ("load off", "generates no load"),
            ("insert 0x101 0 1 2 3 4 5 6 7 8", "at most 8"),
        ] {
            let reply = answer(line);
            assert!(
                reply.starts_with("error ") && reply.contains(words),
                "`{line}`: {reply}"
            );
        }
        let reply = answer("drop 0x102");
        assert_eq!(reply, "ok drop 0x102 t=0.000000");
        let refused = panel.answer(&mut network, Err("line is not UTF-8 text: refused".into()));
        assert_eq!(refused, "error line is not UTF-8 text: refused");
    }

    /// A frame inserted on the control port goes on the bus from the port's own participant.
    #[test]
    fn an_inserted_frame_goes_on_the_bus() {
        let mut network = bus_only();
        let mut panel = Panel::new(&mut network, true);
        let listener = network.join_external("listener");
        let reply = panel.answer(&mut network, Ok("insert 0x7E5 2a".into()));
        assert!(reply.starts_with("ok insert 0x7E5 2a t="), "{reply}");
        network.run_until(1_000_000);
        let delivery = network.receive(listener).expect("the frame on the bus");
        assert_eq!(delivery.frame.id().raw(), 0x7E5);
        assert_eq!(delivery.frame.data(), [0x2A]);
    }

    /// A channel's status: the node's heartbeat state, its EMCY cause and the channel's log
    /// line naming its safe state; a boot-up message clears what was latched (CiA 301
    /// 7.2.8.3.2: a boot-up comes only after a reset or power-on).
    #[test]
    fn cia301_7_2_8_3_2_a_channels_status_follows_heartbeats_emcy_and_its_log() {
        let mut network = bus_only();
        let mut panel = Panel {
            names: vec!["node33a".into(), "node33b".into()],
            channels: vec![
                Channel {
                    node: Some(33),
                    ..Channel::default()
                };
                2
            ],
            nodes: BTreeMap::new(),
            links: vec![("node33-link".into(), [0, 1])],
            own: network.join_external("control"),
            plain: None,
            reported: vec![None; 2],
        };
        let frame = |id: u16, data: &[u8]| CanFrame::new(CanId::new(id).unwrap(), data).unwrap();
        let on_bus = |panel: &mut Panel, from: &str, frame: CanFrame| {
            panel.event(&Event::Frame {
                at: 0,
                from: from.into(),
                frame,
            })
        };
        on_bus(&mut panel, "node33a", frame(0x721, &[0x05]));
        assert!(panel.working(33));
        panel.event(&Event::Output {
            at: 0,
            mcu: 1,
            on: true,
        });
        on_bus(&mut panel, "node1a", frame(0x101, &[1]));
        on_bus(&mut panel, "node1b", frame(0x102, &[0xFE]));
        assert_eq!(panel.status(1).validated, 1);
        assert_eq!(panel.status(0).validated, 0, "its output never came on");
        // The emergency stop: the output goes off, the pairs still reach the consumer.
        panel.event(&Event::Output {
            at: 0,
            mcu: 1,
            on: false,
        });
        on_bus(&mut panel, "node1a", frame(0x101, &[0]));
        on_bus(&mut panel, "node1b", frame(0x102, &[0xFF]));
        assert_eq!(panel.status(1).validated, 2);
        // A SimpleCAN data packet (SC-ID 30h) is a value of its own; a sync (02Fh) is none.
        on_bus(&mut panel, "node1a", frame(0x02F, &[0; 8]));
        on_bus(&mut panel, "node1a", frame(0x030, &[0; 8]));
        assert_eq!(panel.status(1).validated, 3);
        panel.log(1, "Fault(PeerSafeState { cause: 17 })");
        assert!(!panel.status(1).working);
        assert_eq!(panel.status(1).cause, Cause::PeerSafeState.code());
        assert!(panel.status(0).working);
        on_bus(
            &mut panel,
            "node33a",
            frame(
                0x0A1,
                &[0x50, 0x82, 0x11, 1, Cause::SrvtElapsed.code(), 0, 0, 0],
            ),
        );
        assert!(!panel.status(0).working);
        assert_eq!(panel.status(0).cause, Cause::SrvtElapsed.code());
        assert!(!panel.working(33));
        on_bus(&mut panel, "node33a", frame(0x721, &[0x00]));
        assert!(panel.status(0).working && panel.status(1).working);
        assert_eq!(panel.status(1).cause, 0);
        assert_eq!(panel.status(0).nmt, 0);
        // Reported at once, then only on a change or after the period.
        assert_eq!(panel.reports(0).len(), 2);
        assert!(panel.reports(1).is_empty());
        // (A network of no MCU has no link to cut: the wire is marked as `cut` marks it.)
        panel
            .channels
            .iter_mut()
            .for_each(|channel| channel.cut = true);
        let lines = panel.reports(2);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[0].contains(" link=0 "), "{}", lines[0]);
        assert_eq!(panel.reports(2 + REPORT_PERIOD).len(), 2);
    }

    /// The figures measured from outside ride along in the status lines; a figure that grew
    /// (a link gap, a wake-up in progress) does not make a line due before the period, a
    /// change a watcher acts on does.
    #[test]
    fn measured_figures_are_reported_with_the_period_not_at_each_change() {
        let mut network = bus_only();
        let mut panel = Panel::new(&mut network, true);
        panel.names = vec!["node33a".into()];
        panel.channels = vec![Channel {
            node: Some(33),
            ..Channel::default()
        }];
        panel.reported = vec![None];
        assert_eq!(panel.reports(0).len(), 1);
        panel.channels[0].link_gap_ms = 7;
        panel.channels[0].busy_ms = 2;
        panel.channels[0].stack = 1024;
        assert!(panel.reports(1).is_empty());
        let lines = panel.reports(REPORT_PERIOD);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].contains(" stall_ms=0 link_gap_ms=7 busy_ms=2 stack=1024 "),
            "{}",
            lines[0]
        );
        panel.channels[0].cut = true;
        assert_eq!(panel.reports(REPORT_PERIOD + 1).len(), 1);
    }

    /// Over TCP: a client's bad line is answered with a sentence, its good line with `ok`,
    /// and the status lines reach every client.
    #[test]
    fn the_control_port_answers_each_client_and_reports_to_all() {
        use std::io::BufRead as _;
        let mut network = bus_only();
        let mut panel = Panel::new(&mut network, true);
        let mut port = Server::listen("127.0.0.1:0").expect("a port");
        let mut client = TcpStream::connect(port.local_addr()).expect("connected");
        client
            .set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .unwrap();
        client.write_all(b"frobnicate 3\r\ndrop 0x102\n").unwrap();
        let mut lines = std::io::BufReader::new(client.try_clone().unwrap()).lines();
        let mut answers = Vec::new();
        let give_up = std::time::Instant::now() + std::time::Duration::from_secs(5);
        client
            .set_read_timeout(Some(std::time::Duration::from_millis(20)))
            .unwrap();
        while answers.len() < 2 && std::time::Instant::now() < give_up {
            port.serve(&mut panel, &mut network);
            if let Some(Ok(line)) = lines.next() {
                answers.push(line);
            }
        }
        assert_eq!(answers.len(), 2, "{answers:?}");
        assert!(
            answers[0].starts_with("error `frobnicate` with 1 argument(s) is not a command"),
            "{}",
            answers[0]
        );
        assert_eq!(answers[1], "ok drop 0x102 t=0.000000");
        port.write(None, "status node1a t=0.100000");
        client
            .set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .unwrap();
        assert_eq!(
            lines.next().and_then(Result::ok).as_deref(),
            Some("status node1a t=0.100000")
        );
    }

    /// The names of causes in logged safe states.
    #[test]
    fn a_logged_safe_state_names_its_cause() {
        assert_eq!(
            logged_cause(
                "Node(SafeState(Srdo(SrdoFault { srdo: SrdoNumber(1), cause: SrvtElapsed })))"
            ),
            Some(Cause::SrvtElapsed)
        );
        assert_eq!(logged_cause("Node(SafeState(Gfc))"), Some(Cause::Gfc));
        assert_eq!(logged_cause("Node(NmtState(Operational))"), None);
    }
}
