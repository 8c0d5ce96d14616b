//! The runtime's part of SimpleCAN on the two channels (SC_REQ_10, SC_REQ_24), with the
//! checks of [`crate::simplecan`]:
//!
//! - **Forwarding.** Channel A sends every SimpleCAN frame it receives to channel B as it
//!   came off the bus (`Message::SimpleCanPacket`), before its core handles it; channel B
//!   pairs its own reception with A's copy ([`ForwardCheck`](crate::simplecan::ForwardCheck)).
//! - **Both validate.** Each channel's core handles its own reception at once (the slot
//!   timing is judged at the moment the frame came off the bus). For each data packet of an
//!   SC-ID the node consumes, each channel then gives its verdict (SC-ID, cycle stamp,
//!   value, valid): channel A its core's, channel B its core's and its diverse decoder's
//!   together (valid only when both accepted the same fields, `Role::simplecan_decode`).
//!   The verdicts cross the link (`Message::SimpleCanVerdict`) and are compared as SRDO
//!   verdicts are ([`VerdictCheck`](crate::crosscheck::VerdictCheck)).
//! - **Outputs.** A consumed value moves its output towards 0 as soon as this channel
//!   accepts it, and away from 0 only once both channels confirmed it ([`Checks`](crate::simplecan::Checks)).
//! - **Model A.** Channel A transmits the node's packets; channel B keeps its core's and
//!   checks A's on the bus against them ([`TransmitCheck`](crate::simplecan::TransmitCheck));
//!   a packet that agrees is confirmed to B's core as sent, as A's controller confirms A's.
//!
//! Only while the channel's SimpleCAN layer runs (Operational, configuration accepted) and
//! the channel is working: both channels start and stop it on the same NMT frames, so they
//! forward and pair the same frames. Any finding latches both channels' safe state with its
//! own cause (`ChannelFault::SimpleCan`).

use super::{ChannelFault, ChannelProtocol, Collect, Io, Role, Runtime};
use crate::crosscheck::Stream;
use crate::link::{LinkFault, Message};
use crate::simplecan::transmit::TransmitFault;
use crate::simplecan::{Checks, Decoded, OnBus, RawFrame, SimpleCanFault, verdict};
use shared::canopen::storage::Flash;
use shared::{CanFrame, Instant};

impl From<TransmitFault> for SimpleCanFault {
    fn from(fault: TransmitFault) -> Self {
        match fault {
            TransmitFault::Mismatch { id } => SimpleCanFault::TransmitMismatch { id },
            TransmitFault::Missing { id } => SimpleCanFault::TransmitMissing { id },
        }
    }
}

impl<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>> Runtime<F, R, N, P> {
    /// The value this channel drives for the consumed SimpleCAN SC-ID `sc_id` (0: the safe
    /// state, or an SC-ID the node does not consume).
    pub fn simplecan_output(&self, sc_id: u8) -> u32 {
        if self.is_working() {
            self.simplecan.output(sc_id)
        } else {
            0
        }
    }

    /// The board's controller confirmed at `now` that `frame` went out on the bus (a
    /// transmit mailbox completed): SimpleCAN's producers and master must know
    /// (`Device::on_transmitted`; SC_REQ_18, SC_REQ_23). Channel A's board calls it; channel
    /// B sends no SimpleCAN packet, its core learns of the node's packets from A's on the
    /// bus (Model A).
    pub fn on_transmitted(&mut self, now: Instant, frame: &CanFrame, io: &mut impl Io) {
        if !self.link_up {
            return;
        }
        collect!(collect);
        self.node.on_transmitted(now, frame, &mut collect);
        self.after_core(now, &collect, io);
    }

    /// Channel B: channel A's packet on the bus stands for one of B's own, which B's core
    /// learns of as sent (Model A); a sync's time B's master takes from A's, as of when A's
    /// came off the bus (`Device::on_partner_transmitted`).
    fn own_sent(&mut self, now: Instant, on_bus: OnBus, io: &mut impl Io) {
        let OnBus {
            frame: on_bus,
            heard,
        } = on_bus;
        if !self.link_up {
            return;
        }
        // A frame off the bus, or B's own packet, which its core built: a frame either way.
        if let Ok(id) = shared::CanId::new(on_bus.id)
            && let Ok(frame) = CanFrame::from_parts(id, on_bus.len, on_bus.data)
        {
            collect!(collect);
            self.node
                .on_partner_transmitted(now, heard, &frame, &mut collect);
            self.after_core(now, &collect, io);
        }
    }

    /// Channel B sampled its input `plain` at `now`, `before` then `value` (the sample's
    /// bytes, little-endian): for each value the node produces from that object, the
    /// Model A check learns B's sample, and a packet of A's waiting for it stands for B's.
    pub(super) fn simplecan_sampled(
        &mut self,
        now: Instant,
        plain: shared::canopen::od::Address,
        before: u64,
        value: u64,
        io: &mut impl Io,
    ) {
        if self.role.speaks_for_the_node() {
            return;
        }
        let Some(layer) = self.node.protocol().simplecan() else {
            return;
        };
        for entry in layer.produced_from(plain) {
            let bits = entry.mapped & 0xFF;
            let mask = if bits >= 32 {
                u32::MAX
            } else {
                (1u32 << bits) - 1
            };
            // The produced value is the object's bytes, at most 4 (docs/simplecan.md section 2).
            let of = |sample: u64| (sample as u32) & mask;
            let id = u16::from(entry.sc_id);
            if let Some(own) = self
                .simplecan
                .transmit
                .sampled(now, id, of(before), of(value))
                && layer.running
                && self.is_working()
            {
                self.own_sent(now, own, io);
            }
        }
    }

    /// What the EMCY FF02h of `fault` names in bytes 2..=4, as for a foreign frame: the CAN
    /// identifier of the packet concerned (least significant octet first; a consumed entry's
    /// by its SC-ID), and for a copy that differs the identifier of A's copy in byte 4
    /// (SimpleCAN identifiers are 02Fh..07Fh); nothing for an overrun or an unknown entry.
    pub(super) fn simplecan_named(&self, fault: SimpleCanFault) -> [u8; 3] {
        use crate::crosscheck::CrossFault;
        use crate::simplecan::ForwardFault;
        let entry_id = |entry: crate::simplecan::ConsumedEntry| {
            self.node
                .protocol()
                .simplecan()
                .and_then(|layer| layer.entries.get(entry.index()).map(|e| u16::from(e.sc_id)))
        };
        let (id, other) = match fault {
            SimpleCanFault::Forward(ForwardFault::Differs { heard, forwarded }) => {
                (Some(heard), forwarded as u8)
            }
            SimpleCanFault::Forward(ForwardFault::Lost { id } | ForwardFault::Unheard { id })
            | SimpleCanFault::TransmitMismatch { id }
            | SimpleCanFault::TransmitMissing { id } => (Some(id), 0),
            SimpleCanFault::Verdict(
                CrossFault::Disagreement { srdo: entry }
                | CrossFault::Unconfirmed { srdo: entry }
                | CrossFault::QueueFull { srdo: entry },
            ) => (entry_id(entry), 0),
            SimpleCanFault::Forward(ForwardFault::Overrun)
            | SimpleCanFault::Verdict(CrossFault::UnknownSrdo { .. }) => (None, 0),
        };
        let [low, high] = id.unwrap_or(0).to_le_bytes();
        [low, high, other]
    }

    fn simplecan_fault(&mut self, fault: impl Into<SimpleCanFault>, io: &mut impl Io) {
        let fault = fault.into();
        if !self.role.speaks_for_the_node() && self.fault.is_none() {
            // Channel A speaks for the node: its EMCY names what B found (SC_REQ_14).
            self.send(&fault.message(), io);
        }
        self.latch(ChannelFault::SimpleCan(fault), io);
    }

    /// A frame from the bus: `true` when it was a SimpleCAN frame handled here (the caller
    /// does nothing more with it), `false` for the runtime's usual path (not a SimpleCAN
    /// frame, or SimpleCAN not running in a working channel).
    pub(super) fn simplecan_frame(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        io: &mut impl Io,
    ) -> bool {
        let (Some(layer), Some(raw)) = (self.node.protocol().simplecan(), RawFrame::of(frame))
        else {
            return false;
        };
        if !layer.running || !self.is_working() {
            return false;
        }
        if self.role.speaks_for_the_node() {
            // SC_REQ_24: forwarded before anything is made of it, whatever it is.
            self.send(&raw.forward(), io);
        } else if layer.is_own(&raw) {
            // Model A: the node's own packet, channel A's on the bus.
            let decoded = self.role.simplecan_decode(&raw, |id| layer.hash_of(id));
            let buffering = layer.buffering;
            match self.simplecan.transmit.heard(now, raw, decoded, buffering) {
                Ok(Some(own)) => self.own_sent(now, own, io),
                // Its value waits for B's next sample (the window).
                Ok(None) => {}
                Err(fault) => self.simplecan_fault(fault, io),
            }
            return true;
        } else if let Err(fault) = self.simplecan.forward.heard(now, raw) {
            self.simplecan_fault(SimpleCanFault::Forward(fault), io);
            return true;
        }
        collect!(collect);
        self.node.handle_frame(now, frame, &mut collect);
        self.after_core(now, &collect, io);
        self.simplecan_verdict(now, raw, layer.accepted, io);
        true
    }

    /// This channel's verdict on `raw`, a frame its core has just handled having accepted
    /// `accepted_before` data packets before: for a data packet of a consumed SC-ID, sent
    /// to the other channel and entered in the cross-check.
    fn simplecan_verdict(
        &mut self,
        now: Instant,
        raw: RawFrame,
        accepted_before: u32,
        io: &mut impl Io,
    ) {
        let Some(layer) = self.node.protocol().simplecan() else {
            return;
        };
        let consumed = u8::try_from(raw.id)
            .ok()
            .and_then(|sc_id| Some((sc_id, layer.consumed(sc_id)?)));
        let Some((sc_id, entry)) = consumed else {
            return; // Not a data packet the node consumes: nothing to deliver, no verdict.
        };
        if !self.is_working() {
            return; // The core latched on it (1000 bad CRCs): the latch is the reaction.
        }
        let core_accepted = layer.accepted != accepted_before;
        let decoded = self.role.simplecan_decode(&raw, |id| layer.hash_of(id));
        let stamp = raw.data[4];
        let (valid, value) = match decoded {
            Decoded::Data {
                sc_id: decoded_id,
                value,
                cycle_stamp,
            } if core_accepted && decoded_id == sc_id && cycle_stamp == stamp => (true, value),
            _ => (false, 0),
        };
        self.send(
            &Message::SimpleCanVerdict {
                entry: entry.get(),
                sc_id,
                cycle_stamp: stamp,
                value,
                valid,
            },
            io,
        );
        if valid {
            self.simplecan.accepted(entry, sc_id, stamp, value, io);
        }
        let verdict = verdict(sc_id, stamp, value, valid);
        match self.simplecan.verdicts.local(now, entry, verdict) {
            Ok(Some(confirmed)) => self.simplecan_confirmed(entry, sc_id, confirmed, io),
            Ok(None) => {}
            Err(fault) => self.simplecan_fault(SimpleCanFault::Verdict(fault), io),
        }
    }

    fn simplecan_confirmed(
        &mut self,
        entry: crate::simplecan::ConsumedEntry,
        sc_id: u8,
        confirmed: crate::crosscheck::Verdict,
        io: &mut impl Io,
    ) {
        if !self.configuration.confirmed() || !self.is_working() {
            // As for SRDOs: both agree on the value, not yet (in this Operational period) on
            // the configuration that produced it; the output stays where it is.
            return;
        }
        self.simplecan.confirmed(entry, sc_id, confirmed, io);
    }

    /// A SimpleCAN message from the other channel.
    pub(super) fn simplecan_message(&mut self, now: Instant, message: Message, io: &mut impl Io) {
        let running = self
            .node
            .protocol()
            .simplecan()
            .is_some_and(|layer| layer.running);
        if !running || !self.is_working() {
            // Sent before this channel left Operational (or latched): nothing to check any
            // more, and the checks were emptied then.
            return;
        }
        match message {
            Message::SimpleCanPacket { id, len, data } => {
                if self.role.speaks_for_the_node() {
                    // Channel B forwards nothing: not a message of the set in this direction.
                    self.latch(ChannelFault::Link(LinkFault::Malformed), io);
                    return;
                }
                if let Err(fault) = self
                    .simplecan
                    .forward
                    .forwarded(now, RawFrame { id, len, data })
                {
                    self.simplecan_fault(SimpleCanFault::Forward(fault), io);
                }
            }
            Message::SimpleCanVerdict {
                entry,
                sc_id,
                cycle_stamp,
                value,
                valid,
            } => {
                if let Some(stream) = crate::simplecan::ConsumedEntry::from_number(entry) {
                    self.simplecan.peer_reported(stream, cycle_stamp);
                }
                let verdict = verdict(sc_id, cycle_stamp, value, valid);
                match self.simplecan.verdicts.remote(now, entry, verdict) {
                    Ok(Some(confirmed)) => {
                        if let Some(stream) = crate::simplecan::ConsumedEntry::from_number(entry) {
                            self.simplecan_confirmed(stream, sc_id, confirmed, io);
                        }
                    }
                    Ok(None) => {}
                    Err(fault) => self.simplecan_fault(SimpleCanFault::Verdict(fault), io),
                }
            }
            Message::SimpleCanFault { cause, id, other } => {
                // Channel B found it; channel A latches the same fault, so that the node's
                // EMCY names it. Anything else is no message of the set.
                let fault = SimpleCanFault::from_message(cause, id, other)
                    .filter(|_| self.role.speaks_for_the_node())
                    .map_or(
                        ChannelFault::Link(LinkFault::Malformed),
                        ChannelFault::SimpleCan,
                    );
                self.latch(fault, io);
            }
            _ => {}
        }
    }

    /// A frame this channel's core handed out: channel B keeps its SimpleCAN packets for the
    /// Model A check (its role does not send them).
    pub(super) fn simplecan_own(&mut self, now: Instant, frame: &CanFrame, io: &mut impl Io) {
        if self.role.speaks_for_the_node() || self.fault.is_some() {
            return;
        }
        let Some(own) = RawFrame::of(frame) else {
            return;
        };
        match self.simplecan.transmit.computed(now, own) {
            // A's was heard ahead of B's own and stands for it.
            Ok(Some(own)) => self.own_sent(now, own, io),
            Ok(None) => {}
            // The previous packet on its identifier still waits for A's, or more packets wait
            // than the node can have: B's core is not doing what A's can be doing.
            Err(fault) => self.simplecan_fault(fault, io),
        }
    }

    /// The core withdrew the frames on `aborts`: channel A's board withdraws them (channel
    /// B's role sends no SimpleCAN packet, so there is nothing of B's to withdraw; its
    /// Model A check reports A's packet missing when it does not come).
    pub(super) fn simplecan_aborts(&mut self, aborts: &[shared::CanId], io: &mut impl Io) {
        if self.role.speaks_for_the_node() {
            for id in aborts {
                io.abort(*id);
            }
        }
    }

    /// Runs the SimpleCAN checks' time-outs at `now`; returns their next deadline.
    pub(super) fn simplecan_poll(&mut self, now: Instant, io: &mut impl Io) -> Instant {
        let checks: &Checks = &self.simplecan;
        if checks.forward.is_idle() && checks.transmit.is_idle() && checks.verdicts.is_idle() {
            // Nothing waits for a copy, a packet or a verdict: no time-out to run, no
            // deadline (what the checks below find then, without looking at each queue; on
            // a node without SimpleCAN traffic, every poll).
            return Instant::NEVER;
        }
        let fault = checks
            .forward
            .poll(now)
            .map_err(SimpleCanFault::Forward)
            .and_then(|()| checks.transmit.poll(now).map_err(SimpleCanFault::from))
            .and_then(|()| checks.verdicts.poll(now).map_err(SimpleCanFault::Verdict))
            .err();
        if let Some(fault) = fault {
            self.simplecan_fault(fault, io);
        }
        let checks: &Checks = &self.simplecan;
        let forward = checks.forward.deadline().unwrap_or(Instant::NEVER);
        let next = forward
            .min(checks.transmit.deadline())
            .min(checks.verdicts.deadline());
        // A deadline already passed has done its work (the fault is latched).
        if next > now { next } else { Instant::NEVER }
    }
}
