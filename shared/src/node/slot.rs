//! The protocol slot: the interface through which the device shell ([`super::Device`]) drives
//! a safety protocol, and what the shell offers the protocol while it runs ([`Slot`]).

use super::{Event, NodeConfig, PersistError, SafeStateCause, Shell, Sink};
use crate::canopen::node_id::NodeId;
use crate::canopen::od::{AbortCode, Address};
use crate::frame::{CanFrame, CanId};
use crate::process_image::ProcessImage;
use crate::time::Instant;

/// A safety protocol the device shell drives.
///
/// # Division of work
///
/// The shell is the CANopen device every safety protocol of this node runs in: NMT slave
/// (CiA 301 7.3.2), SDO server, heartbeat, EMCY, the GFC (EN 50325-5 7.2), parameter storage
/// (0x1010/0x1011, CiA 301 7.5.2.13/14), the process image and the latched safe state
/// (EN 50325-5 8.2.2). A safety protocol is the part that carries safety data: the CANopen
/// Safety SRDO table ([`super::SrdoTable`], EN 50325-5 7.1, CiA 304 9.5) is one, a second one
/// implements the same trait beside it.
///
/// What the shell does for the protocol:
/// - **NMT.** It calls [`SafetyProtocol::start`] on NMT start (from Pre-operational or
///   Stopped), and changes to Operational only when the protocol accepts its configuration
///   (EN 50325-5 8.3.1: no Operational with a configuration that does not pass its check).
///   It calls [`SafetyProtocol::stop`] whenever the node leaves Operational and before every
///   start, and [`SafetyProtocol::reset`] on NMT reset node and reset communication.
/// - **Frames.** Every received frame goes to [`SafetyProtocol::on_frame`] first, in every
///   NMT state; the shell serves it (NMT, GFC, SDO) only when the protocol says it is not its
///   own.
/// - **Time.** In Operational only, [`SafetyProtocol::poll`] runs at every poll that is due,
///   and [`SafetyProtocol::deadline`] joins the node's next deadline; outside Operational the
///   protocol has no timers (EN 50325-5 8.2.2: safety communication only in Operational).
/// - **Objects.** SDO accesses to an index [`SafetyProtocol::owns`] go to its
///   [`read`](SafetyProtocol::read) and [`write`](SafetyProtocol::write), with the NMT state,
///   so that it applies EN 50325-5 8.2.2 (safety objects read-only in Operational). No
///   application object may use one of its indices.
/// - **Storage.** 0x1010 stores the shell's parameters followed by the protocol's section
///   ([`SafetyProtocol::persist`]); at power-on and reset the protocol gets its defaults
///   ([`SafetyProtocol::load_defaults`]) and then its stored section, if any
///   ([`SafetyProtocol::restore`]). Stored under another node-ID, the section is restored but
///   its validation withdrawn ([`SafetyProtocol::withdraw_validation`]; IEC 61784-3
///   addressing).
/// - **Access.** The shell's access control (SC_REQ_43, [`super::access`]) refuses, while
///   the device is locked, every write to an object [`SafetyProtocol::needs_unlock`] names,
///   before the protocol sees it; after an accepted one it records a validated change with
///   the protocol's [`SafetyProtocol::validated_signatures`] in the audit record, which is
///   stored with the shell's parameters, not in the protocol's section.
/// - **Safe state.** The shell owns the latch: one cause, EMCY, the
///   [`SafeState`](super::Event::SafeState) event, the GFC when configured. When it latches
///   for a cause of its own (a GFC, the application, ...), it first tells the protocol
///   ([`SafetyProtocol::enter_safe_state`]), which puts every value it received in the safe
///   state (0, SC_REQ_05) and stops what must stop.
///
/// What a protocol must do:
/// - Validate its whole configuration in [`start`](SafetyProtocol::start) and either run it
///   or refuse it through [`Slot::refuse_configuration`] (which reports it: EMCY 6300h), left
///   stopped and with its validation withdrawn (EN 50325-5 6.4.1.6).
/// - Never deliver data while [`Slot::latched`], and report each fault it detects with
///   [`Slot::latch`] after putting its own received values in the safe state
///   (`enter_safe_state` with the same cause): the latch is the shell's, the values are the
///   protocol's.
/// - Report its earliest timer in [`deadline`](SafetyProtocol::deadline), never later than the
///   timer, and pull the node's next poll earlier with [`Slot::wake_at`] when a frame starts a
///   timer (a consumer's SRVT, say) between polls.
/// - Persist everything a tool configures, all or nothing on restore, within
///   [`SafetyProtocol::MAX_PERSISTED`] bytes.
///
/// A protocol whose fault the shell's causes do not name latches with
/// [`SafeStateCause::Protocol`], giving the EMCY itself.
///
/// No `dyn`, no heap: the device is generic over its protocol, so each call is static and the
/// firmware image carries only the protocol it runs. One protocol per device: two at once
/// (CANopen Safety beside SimpleCAN) would be one implementation of this trait holding both.
pub trait SafetyProtocol {
    /// The largest section [`SafetyProtocol::persist`] writes, in bytes. At most the section
    /// of the largest SRDO table (64 SRDOs, 16 mapping entries each: 5,058 bytes), checked
    /// when the device is built.
    const MAX_PERSISTED: usize;

    /// A buffer for the device's whole stored image with this protocol's section: the shell's
    /// header and access part and at most [`SafetyProtocol::MAX_PERSISTED`] bytes (checked
    /// when the device is built). Sized for this device, not for the largest one: it is on
    /// the stack while the parameters are stored or restored, the deepest point of start-up.
    type Image: AsRef<[u8]> + AsMut<[u8]>;

    /// A zeroed [`SafetyProtocol::Image`].
    fn image() -> Self::Image;

    /// Its configuration back to the device's defaults (power-on, NMT reset, and before a
    /// stored section is restored).
    fn load_defaults(&mut self, config: &NodeConfig);

    /// Writes its stored section into `out` (at least [`SafetyProtocol::MAX_PERSISTED`]
    /// bytes) and returns the length written.
    fn persist(&self, out: &mut [u8]) -> usize;

    /// Restores its configuration from a section [`SafetyProtocol::persist`] wrote, exactly
    /// `bytes` long. All or nothing: on an error the configuration is unchanged.
    fn restore(&mut self, bytes: &[u8]) -> Result<(), PersistError>;

    /// Withdraws the validation of its configuration (EN 50325-5 6.4.1.6: 0x13FE reads 0), as
    /// when it was restored on a node-ID it was not validated for.
    fn withdraw_validation(&mut self);

    /// `true` when `index` is one of its objects (answered by [`SafetyProtocol::read`] and
    /// [`SafetyProtocol::write`], whether or not the sub-index exists).
    fn owns(&self, index: u16) -> bool;

    /// `true` for those of its objects ([`SafetyProtocol::owns`]) whose writes change its
    /// safety configuration: the shell lets them through only while the device is open or
    /// unlocked (SC_REQ_43, [`super::access`]), as it does 0x1010 and 0x1011. An associated
    /// function: which objects are safety configuration is the protocol's object model, not
    /// its state, and a configuration tool asks the same question without a device.
    fn needs_unlock(index: u16) -> bool;

    /// The signatures of its configuration, one per part (the SRDO table: one per SRDO, as
    /// 0x13FF holds them), as the audit record of validated changes keeps them (SC_REQ_43,
    /// 5C12h and 5C13h). An array, so that the record has the protocol's size.
    type Signatures: Copy + Eq + core::fmt::Debug + AsRef<[u16]> + AsMut<[u16]>;

    /// The signatures of a configuration never validated: every one 0.
    const NO_SIGNATURES: Self::Signatures;

    /// The signatures of its configuration while that is validated (the SRDO table: 0x13FE
    /// reads A5h, EN 50325-5 6.4.1.6), `None` otherwise. The shell asks after every accepted
    /// write to an object [`SafetyProtocol::needs_unlock`] names, and records a validated
    /// change in the audit when it gets signatures other than the last recorded ones; so an
    /// accepted write that is not the validation itself must withdraw the validation.
    fn validated_signatures(&self) -> Option<Self::Signatures>;

    /// Reads one of its objects by SDO rules.
    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode>;

    /// Writes one of its objects by SDO rules; `operational` in NMT Operational.
    fn write(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode>;

    /// Entering Operational at `now`: checks the whole configuration and starts running it,
    /// or refuses it through [`Slot::refuse_configuration`]. The shell has stopped it just
    /// before.
    fn start<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Result<(), Refused>;

    /// Leaving Operational (or before a start): stops every timer and puts every value it
    /// received in the safe state in `image`.
    fn stop(&mut self, image: &mut ProcessImage);

    /// NMT reset node or reset communication: what it counts since power-on, and what it
    /// halted for the latched safe state, back to the start (it is already stopped).
    fn reset(&mut self);

    /// A frame received at `now`, in any NMT state: `true` when it is its own (the shell then
    /// does nothing more with it).
    fn on_frame<S: Sink>(&mut self, now: Instant, frame: &CanFrame, slot: &mut Slot<'_, S>)
    -> bool;

    /// Runs every timer due at `now` (Operational only).
    fn poll<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>);

    /// Its earliest timer (Operational only; [`Instant::NEVER`] when none runs). `latched`:
    /// the device is in its latched safe state.
    #[must_use]
    fn deadline(&self, now: Instant, latched: bool) -> Instant;

    /// The device enters (`already_latched == false`) or is already in its latched safe state
    /// for `cause`: every value it received to the safe state in `image` (on entering), and
    /// stop what `cause` says must stop.
    fn enter_safe_state(
        &mut self,
        image: &mut ProcessImage,
        cause: SafeStateCause,
        already_latched: bool,
    );

    /// The application changed the process image byte at `offset`: `true` when that makes the
    /// protocol due at once (event-driven transmission, EN 50325-5 6.2.1).
    fn object_changed(&mut self, offset: u8) -> bool;

    /// The controller confirmed that `frame` went out on the bus at `now`
    /// ([`super::Device::on_transmitted`]). Only a protocol that must know (SimpleCAN's syncs,
    /// SC_REQ_23) acts on it; the SRDO table does not.
    fn on_transmitted<S: Sink>(&mut self, now: Instant, frame: &CanFrame, slot: &mut Slot<'_, S>) {
        let _ = (now, frame, slot);
    }

    /// The other channel of a dual-channel device put `frame` on the bus, heard at `heard`
    /// (at or before `now`), for a frame this protocol handed out (Model A: this channel
    /// computes, the other transmits; [`super::Device::on_partner_transmitted`]). The default
    /// is the confirmation of [`SafetyProtocol::on_transmitted`] at `now`; SimpleCAN also
    /// takes the time of a sync from it.
    fn on_partner_transmitted<S: Sink>(
        &mut self,
        now: Instant,
        heard: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) {
        let _ = heard;
        self.on_transmitted(now, frame, slot);
    }
}

/// A start the protocol refused; made only by [`Slot::refuse_configuration`], so a refusal is
/// always reported.
#[derive(Debug, PartialEq, Eq)]
pub struct Refused(());

/// What the shell offers a protocol during one call: the process image, the sink, the latch
/// and the node's next deadline.
pub struct Slot<'a, S: Sink> {
    pub(super) shell: &'a mut Shell,
    pub(super) image: &'a mut ProcessImage,
    pub(super) sink: &'a mut S,
}

impl<S: Sink> Slot<'_, S> {
    /// The same slot, by value, for one call: what an out-of-line (cold) callee takes, so
    /// that the hot caller's slot stays in registers rather than in memory for a reference.
    pub fn reborrow(&mut self) -> Slot<'_, S> {
        Slot {
            shell: self.shell,
            image: self.image,
            sink: self.sink,
        }
    }

    /// The node-ID.
    pub fn node_id(&self) -> NodeId {
        self.shell.config.node_id
    }

    /// `true` in the latched safe state: nothing may be delivered.
    pub fn latched(&self) -> bool {
        self.shell.fault.is_some()
    }

    /// The application objects' values.
    pub fn image(&self) -> &ProcessImage {
        self.image
    }

    /// The application objects' values, to deliver received data into.
    pub fn image_mut(&mut self) -> &mut ProcessImage {
        self.image
    }

    /// Sends `frame` on the bus.
    pub fn transmit(&mut self, frame: CanFrame) {
        self.sink.transmit(frame);
    }

    /// Withdraws the frames on `id` not yet on the bus ([`Sink::abort`]).
    pub fn abort(&mut self, id: CanId) {
        self.sink.abort(id);
    }

    /// Reports `event` to the application.
    pub fn event(&mut self, event: Event) {
        self.sink.event(event);
    }

    /// Latches the device's safe state for `cause` (once: EMCY, event, GFC when configured).
    /// The protocol has put its own values in the safe state before.
    pub fn latch(&mut self, cause: SafeStateCause) {
        self.shell.latch(cause, self.sink);
    }

    /// Polls the node no later than `at`.
    pub fn wake_at(&mut self, at: Instant) {
        self.shell.next_deadline = self.shell.next_deadline.min(at);
    }

    /// Reports a configuration refused at Operational entry (EN 50325-5 8.3.1): the error
    /// register, EMCY 6300h (data set) with `detail` as its manufacturer-specific bytes, and
    /// `event`. The device stays in its NMT state, in the safe state.
    pub fn refuse_configuration(&mut self, detail: [u8; 5], event: Event) -> Refused {
        self.shell.refuse_configuration(detail, self.sink);
        self.sink.event(event);
        Refused(())
    }
}

/// A stored image of `N` rows of `ROW` bytes, zeroed: what a protocol whose persisted
/// section grows with a count (`N` SRDOs, `N` entries) gives as its
/// [`SafetyProtocol::Image`], so that a small device restores its parameters through a small
/// buffer on the stack. An array of arrays, because its length is `N` itself, which stable
/// Rust allows (`[u8; ROW * N]` it does not).
pub struct RowImage<const ROW: usize, const N: usize>([[u8; ROW]; N]);

impl<const ROW: usize, const N: usize> RowImage<ROW, N> {
    /// The zeroed image.
    pub const fn zeroed() -> Self {
        RowImage([[0; ROW]; N])
    }
}

impl<const ROW: usize, const N: usize> AsRef<[u8]> for RowImage<ROW, N> {
    fn as_ref(&self) -> &[u8] {
        self.0.as_flattened()
    }
}

impl<const ROW: usize, const N: usize> AsMut<[u8]> for RowImage<ROW, N> {
    fn as_mut(&mut self) -> &mut [u8] {
        self.0.as_flattened_mut()
    }
}
