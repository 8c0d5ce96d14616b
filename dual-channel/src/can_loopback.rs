//! The dynamic test of the CAN controller's message buffers and acceptance filters at start-up
//! (CiA 304 9.5: the CAN message buffers are tested dynamically; EN 50325-5 Annex A.4).
//!
//! The hardware layer puts the bxCAN in silent loop-back mode (nothing reaches the bus, so
//! the running network is not disturbed), sets two filter banks in list mode, [`ACCEPT_FIFO0`]
//! to receive FIFO 0 and [`ACCEPT_FIFO1`] to FIFO 1, and hands the controller to [`run`]
//! through [`LoopbackController`]. [`run`] sends [`PLAN`] burst by burst, each burst back to
//! back so that its frames occupy transmit mailboxes 0, 1 and 2, and feeds what comes back to
//! [`LoopbackCheck`], which gives the verdict. The plan is chosen so that every single stuck-at
//! fault of an identifier, length or data bit, in any transmit mailbox and in either receive
//! FIFO, changes at least one frame:
//!
//! - every transmit mailbox carries a pair of identifiers complementary in all 11 bits,
//!   lengths 0, 7 and 8 (each length bit at 0 and at 1, and every stuck bit changes one of
//!   them into another length) and data 55h and AAh in all eight bytes;
//! - each receive FIFO gets the same lengths and patterns, and its complementary pair of
//!   identifiers;
//! - each accepted identifier with its lowest bit flipped is sent and must be filtered out.
//!
//! The host tests run [`run`] on a simulated controller with each of those faults and require
//! a failed verdict for every one. What this test cannot see: which FIFO a frame came through
//! (embassy-stm32's driver merges both), so filter *routing* is not checked, only that each
//! filter passes its identifiers and not those one bit away; nor are the filter registers'
//! other bits covered.

use shared::{CanFrame, CanId, Duration, Instant};

/// The identifiers receive FIFO 0's filter bank lists (complementary in all 11 bits).
pub const ACCEPT_FIFO0: [u16; 2] = [0x555, 0x2AA];
/// The identifiers receive FIFO 1's filter bank lists (complementary in all 11 bits).
pub const ACCEPT_FIFO1: [u16; 2] = [0x5AA, 0x255];
/// The bxCAN's transmit mailboxes.
pub const MAILBOXES: u8 = 3;

/// One frame of the plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TestFrame {
    /// 11-bit identifier.
    pub id: u16,
    /// Data length code.
    pub dlc: u8,
    /// Every data byte has this value.
    pub fill: u8,
}

impl TestFrame {
    const fn new(id: u16, dlc: u8, fill: u8) -> TestFrame {
        TestFrame { id, dlc, fill }
    }

    /// `true` when a filter lets it through.
    pub const fn accepted(self) -> bool {
        self.id == ACCEPT_FIFO0[0]
            || self.id == ACCEPT_FIFO0[1]
            || self.id == ACCEPT_FIFO1[0]
            || self.id == ACCEPT_FIFO1[1]
    }

    /// The frame to send; `None` only for an identifier over 11 bits or a length over 8,
    /// which the plan does not hold (a test checks it) and which [`run`] would report as a
    /// refused frame rather than panic.
    pub fn frame(self) -> Option<CanFrame> {
        let data = [self.fill; 8];
        let id = CanId::new(self.id).ok()?;
        CanFrame::new(id, data.get(..usize::from(self.dlc))?).ok()
    }

    fn matches(self, frame: &CanFrame) -> bool {
        !frame.is_remote()
            && frame.id().raw() == self.id
            && frame.dlc() == self.dlc
            && frame.data().iter().all(|&byte| byte == self.fill)
    }
}

/// The frames in bursts; within a burst the `k`-th frame takes transmit mailbox `k`. Each
/// mailbox carries a complementary pair of identifiers, lengths 0, 7 and 8 (each length bit
/// at 0 and at 1, and every stuck bit turns one of them into another length) and 55h and AAh
/// in all eight bytes; so does each receive FIFO, with both of its identifiers. Frames within
/// a burst differ; a frame may repeat in another burst, in another mailbox. The last two
/// bursts are the identifiers one bit away from each accepted one.
pub const PLAN: [&[TestFrame]; 6] = {
    let [a, b] = ACCEPT_FIFO0;
    let [c, d] = ACCEPT_FIFO1;
    [
        &[
            TestFrame::new(a, 8, 0x55),
            TestFrame::new(b, 0, 0x00),
            TestFrame::new(c, 7, 0x55),
        ],
        &[
            TestFrame::new(b, 8, 0xAA),
            TestFrame::new(a, 7, 0x55),
            TestFrame::new(d, 0, 0x00),
        ],
        &[
            TestFrame::new(c, 0, 0x00),
            TestFrame::new(d, 8, 0x55),
            TestFrame::new(a, 8, 0xAA),
        ],
        &[
            TestFrame::new(d, 7, 0x55),
            TestFrame::new(c, 8, 0xAA),
            TestFrame::new(b, 8, 0x55),
        ],
        &[
            TestFrame::new(a ^ 1, 1, 0x55),
            TestFrame::new(b ^ 1, 1, 0xAA),
        ],
        &[
            TestFrame::new(c ^ 1, 1, 0x55),
            TestFrame::new(d ^ 1, 1, 0xAA),
        ],
    ]
};

/// Frames in the plan.
const FRAMES: usize = 16;

/// The plan's frame `index` (bursts counted through).
fn planned(index: usize) -> Option<TestFrame> {
    PLAN.iter()
        .flat_map(|burst| burst.iter())
        .nth(index)
        .copied()
}

/// The index of the first frame of `burst`.
fn first_of(burst: usize) -> usize {
    PLAN.iter().take(burst).map(|b| b.len()).sum()
}

/// Why the CAN controller failed its loop-back test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoopbackFault {
    /// The controller refused frame `index` (no mailbox free).
    Refused(u8),
    /// A transmit mailbox was never used, so it is untested.
    MailboxUnused(u8),
    /// Frame `index`, which a filter accepts, did not come back.
    Missing(u8),
    /// Frame `index` came back more than once.
    Duplicated(u8),
    /// Frame `index`, which no filter accepts, came back.
    FilterLeak(u8),
    /// The controller reported a bus error, which silent loop-back mode cannot have.
    BusError,
    /// A frame came back that was never sent: a bit changed on the way (identifier `id`,
    /// length `dlc` as received).
    Altered {
        /// Identifier as received.
        id: u16,
        /// Length as received.
        dlc: u8,
    },
}

/// The verdict of one loop-back run, fed with what the controller did.
#[derive(Clone, Debug, Default)]
pub struct LoopbackCheck {
    /// The burst being sent: a frame that comes back is matched against its frames only
    /// (the same frame may appear in two bursts, in another mailbox).
    burst: usize,
    received: [u8; FRAMES],
    mailboxes: u8,
    fault: Option<LoopbackFault>,
}

impl LoopbackCheck {
    /// A run before the first frame.
    pub fn new() -> LoopbackCheck {
        LoopbackCheck::default()
    }

    fn record(&mut self, fault: LoopbackFault) {
        self.fault.get_or_insert(fault);
    }

    /// `burst` of [`PLAN`] is sent next; the frames of the earlier ones are all back.
    pub fn start_burst(&mut self, burst: usize) {
        self.burst = burst;
    }

    /// Frame `index` was queued into `mailbox`, or refused (`None`).
    pub fn on_queued(&mut self, index: usize, mailbox: Option<u8>) {
        match mailbox {
            Some(mailbox) if mailbox < MAILBOXES => self.mailboxes |= 1 << mailbox,
            _ => self.record(LoopbackFault::Refused(index as u8)),
        }
    }

    /// A frame came back from the controller.
    pub fn on_received(&mut self, frame: &CanFrame) {
        let first = first_of(self.burst);
        let found = PLAN
            .get(self.burst)
            .into_iter()
            .flat_map(|burst| burst.iter())
            .enumerate()
            .find(|(_, plan)| plan.matches(frame))
            .map(|(k, plan)| (first + k, *plan));
        match found {
            Some((index, plan)) if plan.accepted() => {
                self.received[index] = self.received[index].saturating_add(1);
                if self.received[index] > 1 {
                    self.record(LoopbackFault::Duplicated(index as u8));
                }
            }
            Some((index, _)) => self.record(LoopbackFault::FilterLeak(index as u8)),
            None => self.record(LoopbackFault::Altered {
                id: frame.id().raw(),
                dlc: frame.dlc(),
            }),
        }
    }

    /// A frame came back that is not a CANopen frame (an extended identifier, or a length
    /// over 8): a bit changed on the way.
    pub fn on_unreadable(&mut self, id: u16, dlc: u8) {
        self.record(LoopbackFault::Altered { id, dlc });
    }

    /// The controller reported a bus error.
    pub fn on_bus_error(&mut self) {
        self.record(LoopbackFault::BusError);
    }

    /// `true` once every accepted frame of `burst` came back (the caller may stop waiting).
    pub fn burst_complete(&self, burst: usize) -> bool {
        let first = first_of(burst);
        PLAN.get(burst).is_some_and(|frames| {
            frames
                .iter()
                .enumerate()
                .all(|(k, f)| !f.accepted() || self.received[first + k] > 0)
        })
    }

    /// The verdict once every burst was sent and given time to come back.
    pub fn verdict(&self) -> Result<(), LoopbackFault> {
        if let Some(fault) = self.fault {
            return Err(fault);
        }
        if let Some(missing) = (0..FRAMES)
            .find(|&i| planned(i).is_some_and(TestFrame::accepted) && self.received[i] == 0)
        {
            return Err(LoopbackFault::Missing(missing as u8));
        }
        match (0..MAILBOXES).find(|m| self.mailboxes & (1 << m) == 0) {
            Some(unused) => Err(LoopbackFault::MailboxUnused(unused)),
            None => Ok(()),
        }
    }
}

/// How long a burst may take to come back: three frames take under 1 ms at 500 kbit/s.
pub const BURST_WAIT: Duration = Duration::from_millis(5);
/// How long the test goes on listening once a burst is back, for frames that should not come
/// (a doubled frame, a filter that leaks).
pub const SETTLE: Duration = Duration::from_millis(1);

/// What came out of the controller's receive side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A CANopen frame.
    Frame(CanFrame),
    /// A frame that is not CANopen's (extended identifier, length over 8), as received.
    Unreadable {
        /// Identifier, cut to 16 bits.
        id: u16,
        /// Length code.
        dlc: u8,
    },
    /// The controller reported a bus error.
    BusError,
    /// Nothing came before the deadline.
    Nothing,
}

/// The CAN controller in silent loop-back mode, with the two filter banks of [`ACCEPT_FIFO0`]
/// and [`ACCEPT_FIFO1`] set: the hardware layer's side of the test.
pub trait LoopbackController {
    /// Now, on the board's clock.
    fn now(&self) -> Instant;
    /// Queues `frame` for transmission at once; the mailbox it took, or `None` when refused.
    fn queue(&mut self, frame: &CanFrame) -> Option<u8>;
    /// The next frame from either receive FIFO, or [`Received::Nothing`] at `until`: waits
    /// for one (the test runs at start-up, before the channel loop, with nothing else to do).
    fn receive(&mut self, until: Instant) -> Received;
}

/// Runs the whole plan on `controller` (and calls `between_bursts` before each burst, for
/// the watchdog): each burst queued back to back, then read back until every accepted frame of
/// it is there and [`SETTLE`] more has passed, or [`BURST_WAIT`] is over.
pub fn run<C: LoopbackController>(
    controller: &mut C,
    mut between_bursts: impl FnMut(),
) -> Result<(), LoopbackFault> {
    let mut check = LoopbackCheck::new();
    let mut index = 0;
    for (number, burst) in PLAN.iter().enumerate() {
        between_bursts();
        check.start_burst(number);
        for plan in burst.iter() {
            let mailbox = plan.frame().and_then(|frame| controller.queue(&frame));
            check.on_queued(index, mailbox);
            index += 1;
        }
        let mut until = controller.now() + BURST_WAIT;
        let mut settling = false;
        loop {
            if !settling && check.burst_complete(number) {
                settling = true;
                until = until.min(controller.now() + SETTLE);
            }
            match controller.receive(until) {
                Received::Frame(frame) => check.on_received(&frame),
                Received::Unreadable { id, dlc } => check.on_unreadable(id, dlc),
                Received::BusError => check.on_bus_error(),
                Received::Nothing => break,
            }
        }
    }
    check.verdict()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;
    use std::rc::Rc;
    use std::vec::Vec;

    /// Where a bit is stuck.
    #[derive(Clone, Copy, Debug)]
    enum Place {
        /// In transmit mailbox `n`.
        Mailbox(usize),
        /// In receive FIFO `n`.
        Fifo(usize),
    }

    /// A register bit stuck at a value: identifier bit 0..11, length bit 11..15, data bit
    /// 15..79 (byte-major).
    #[derive(Clone, Copy, Debug)]
    struct Stuck {
        place: Place,
        bit: usize,
        value: bool,
    }

    /// Every single stuck-at fault of the registers the plan is meant to cover.
    fn every_stuck_bit() -> Vec<Stuck> {
        let places = (0..3).map(Place::Mailbox).chain((0..2).map(Place::Fifo));
        places
            .flat_map(|place| {
                (0..11 + 4 + 64)
                    .flat_map(move |bit| [false, true].map(|value| Stuck { place, bit, value }))
            })
            .collect()
    }

    /// (identifier, length, data) as held in a register.
    type Register = (u16, u8, [u8; 8]);

    fn apply(stuck: Stuck, (mut id, mut dlc, mut data): Register) -> Register {
        let set = |word: &mut u16, bit: usize| {
            if stuck.value {
                *word |= 1 << bit
            } else {
                *word &= !(1 << bit)
            }
        };
        match stuck.bit {
            bit @ 0..11 => set(&mut id, bit),
            bit @ 11..15 => {
                let mut wide = u16::from(dlc);
                set(&mut wide, bit - 11);
                dlc = wide as u8;
            }
            bit => {
                let (byte, bit) = ((bit - 15) / 8, (bit - 15) % 8);
                let mut wide = u16::from(data[byte]);
                set(&mut wide, bit);
                data[byte] = wide as u8;
            }
        }
        (id, dlc, data)
    }

    /// A model of the bxCAN in silent loop-back mode with two exact filters, and the faults
    /// the test is meant to find.
    #[derive(Clone, Copy, Debug, Default)]
    struct Controller {
        stuck: Option<Stuck>,
        /// The filters accept every identifier.
        filters_open: bool,
        /// Frames through FIFO 1 are lost.
        fifo1_lost: bool,
        /// Every frame is delivered twice.
        doubled: bool,
        /// The mailbox chosen is always 0 (a mailbox that never frees stays unused).
        one_mailbox: bool,
    }

    impl Controller {
        fn stuck_at(&self, place: Place) -> Option<Stuck> {
            self.stuck.filter(|s| {
                matches!(
                    (s.place, place),
                    (Place::Mailbox(a), Place::Mailbox(b)) | (Place::Fifo(a), Place::Fifo(b)) if a == b
                )
            })
        }

        /// What one frame becomes on its way through mailbox `mailbox`, the filters and a
        /// FIFO: the FIFO it lands in and what the software reads, or `None` when filtered.
        fn deliver(&self, mailbox: usize, plan: &CanFrame) -> Option<Received> {
            let mut register = (plan.id().raw(), plan.dlc(), [0u8; 8]);
            register.2[..usize::from(plan.dlc())].copy_from_slice(plan.data());
            if let Some(stuck) = self.stuck_at(Place::Mailbox(mailbox)) {
                register = apply(stuck, register);
            }
            let id = register.0;
            let fifo = if ACCEPT_FIFO0.contains(&id) {
                0
            } else if ACCEPT_FIFO1.contains(&id) {
                1
            } else if self.filters_open {
                usize::from(id & 1)
            } else {
                return None;
            };
            if fifo == 1 && self.fifo1_lost {
                return None;
            }
            if let Some(stuck) = self.stuck_at(Place::Fifo(fifo)) {
                register = apply(stuck, register);
            }
            let (id, dlc, data) = register;
            // A length over 8 is not a CANopen frame.
            Some(match data.get(..usize::from(dlc)) {
                Some(data) => {
                    Received::Frame(CanFrame::new(CanId::new(id).unwrap(), data).unwrap())
                }
                None => Received::Unreadable { id, dlc },
            })
        }

        /// Runs the whole plan through [`run`], as the hardware layer does.
        fn run(self) -> Result<(), LoopbackFault> {
            let mut bus = Simulated::new(self);
            let verdict = run(&mut bus, || {});
            assert_eq!(bus.queued, FRAMES, "every frame was queued");
            verdict
        }
    }

    /// Simulated time and the controller: frames leave one after the other, each `latency`
    /// after the one before, and free their mailbox when they have come back; the lowest free
    /// mailbox takes the next frame. An empty wait moves time to its deadline.
    struct Simulated {
        controller: Controller,
        now: Rc<Cell<Instant>>,
        latency: Duration,
        /// When each mailbox is free again.
        busy_until: [Instant; 3],
        /// Frames that arrive, in time order.
        pending: Vec<(Instant, Received)>,
        queued: usize,
    }

    impl Simulated {
        fn new(controller: Controller) -> Self {
            Simulated {
                controller,
                now: Rc::new(Cell::new(Instant::from_millis(0))),
                latency: Duration::from_micros(250),
                busy_until: [Instant::from_millis(0); 3],
                pending: Vec::new(),
                queued: 0,
            }
        }
    }

    impl LoopbackController for Simulated {
        fn now(&self) -> Instant {
            self.now.get()
        }

        fn queue(&mut self, frame: &CanFrame) -> Option<u8> {
            let now = self.now.get();
            let free = (0..3).find(|&m| self.busy_until[m] <= now)?;
            let mailbox = if self.controller.one_mailbox { 0 } else { free };
            let leaves = self.busy_until.iter().copied().max().unwrap().max(now);
            let at = leaves + self.latency;
            self.busy_until[mailbox] = at;
            self.queued += 1;
            if let Some(received) = self.controller.deliver(mailbox, frame) {
                self.pending.push((at, received));
                if self.controller.doubled {
                    self.pending.push((at + self.latency, received));
                }
                self.pending.sort_by_key(|(at, _)| *at);
            }
            Some(mailbox as u8)
        }

        fn receive(&mut self, until: Instant) -> Received {
            match self.pending.first().copied() {
                Some((at, received)) if at <= until => {
                    self.pending.remove(0);
                    self.now.set(self.now.get().max(at));
                    received
                }
                _ => {
                    self.now.set(self.now.get().max(until));
                    Received::Nothing
                }
            }
        }
    }

    #[test]
    fn the_plan_is_what_the_module_says() {
        let all: Vec<TestFrame> = PLAN.iter().flat_map(|b| b.iter().copied()).collect();
        assert_eq!(all.len(), FRAMES);
        assert!(
            PLAN.iter()
                .all(|burst| burst.len() <= usize::from(MAILBOXES))
        );
        for frame in &all {
            let built = frame.frame().expect("a valid frame");
            assert!(frame.matches(&built));
        }
        assert_eq!(all.iter().filter(|f| !f.accepted()).count(), 4);
    }

    /// CiA 304 9.5: a healthy controller passes.
    #[test]
    fn cia304_9_5_a_healthy_controller_passes_the_loopback_test() {
        assert_eq!(Controller::default().run(), Ok(()));
    }

    /// CiA 304 9.5: every single stuck-at bit in the identifier, length or data of any
    /// transmit mailbox or receive FIFO fails the test.
    #[test]
    fn cia304_9_5_every_stuck_bit_of_a_message_buffer_is_found() {
        let faults = every_stuck_bit();
        assert_eq!(faults.len(), 5 * 79 * 2);
        for stuck in faults {
            let verdict = Controller {
                stuck: Some(stuck),
                ..Controller::default()
            }
            .run();
            assert!(verdict.is_err(), "{stuck:?} passed");
        }
    }

    /// CiA 304 9.5: filters that pass what they should not, a lost FIFO, a doubled frame and an
    /// untested mailbox each fail the test, with the fault named.
    #[test]
    fn cia304_9_5_filter_fifo_and_mailbox_faults_are_named() {
        let run = |controller: Controller| controller.run();
        assert_eq!(
            run(Controller {
                filters_open: true,
                ..Controller::default()
            }),
            Err(LoopbackFault::FilterLeak(12))
        );
        assert_eq!(
            run(Controller {
                fifo1_lost: true,
                ..Controller::default()
            }),
            Err(LoopbackFault::Missing(2))
        );
        assert_eq!(
            run(Controller {
                doubled: true,
                ..Controller::default()
            }),
            Err(LoopbackFault::Duplicated(0))
        );
        assert_eq!(
            run(Controller {
                one_mailbox: true,
                ..Controller::default()
            }),
            Err(LoopbackFault::MailboxUnused(1))
        );
        let mut refused = LoopbackCheck::new();
        refused.on_queued(4, None);
        assert_eq!(refused.verdict(), Err(LoopbackFault::Refused(4)));
        let mut errored = LoopbackCheck::new();
        errored.on_bus_error();
        assert_eq!(errored.verdict(), Err(LoopbackFault::BusError));
    }

    /// The watchdog is fed before every burst, and no burst keeps the test longer than
    /// [`BURST_WAIT`]: a healthy run ends after about 1.75 ms per burst (three frames and
    /// [`SETTLE`]), a controller too slow to answer within the wait fails.
    #[test]
    fn bursts_end_in_time_and_a_slow_controller_fails() {
        for (latency_us, healthy) in [(250, true), (2_000, false)] {
            let mut bus = Simulated::new(Controller::default());
            bus.latency = Duration::from_micros(latency_us);
            let clock = bus.now.clone();
            let mut fed = Vec::new();
            let verdict = run(&mut bus, || fed.push(clock.get()));
            fed.push(clock.get());
            assert_eq!(fed.len(), PLAN.len() + 1);
            let longest = fed
                .windows(2)
                .map(|w| w[1].as_micros() - w[0].as_micros())
                .max()
                .unwrap();
            assert!(
                longest <= BURST_WAIT.as_micros(),
                "a burst took {longest} µs"
            );
            if healthy {
                assert_eq!(verdict, Ok(()));
                assert!(
                    clock.get() <= Instant::from_micros(6 * 1_750),
                    "{:?}",
                    clock.get()
                );
            } else {
                // Frames still in flight when the wait ends: the next burst finds the
                // mailboxes busy, or the frames are missing at the verdict.
                assert!(
                    matches!(
                        verdict,
                        Err(LoopbackFault::Refused(_) | LoopbackFault::Missing(_))
                    ),
                    "{verdict:?}"
                );
            }
        }
    }

    #[test]
    fn a_burst_is_complete_once_its_accepted_frames_are_back() {
        let mut check = LoopbackCheck::new();
        assert!(!check.burst_complete(0));
        for plan in PLAN[0] {
            check.on_received(&plan.frame().unwrap());
        }
        assert!(check.burst_complete(0) && !check.burst_complete(1));
        // Burst 2 repeats frames of burst 0 in other mailboxes: not yet back.
        check.start_burst(2);
        assert!(!check.burst_complete(2));
        // The last burst has only frames that must not come back: complete at once.
        check.start_burst(4);
        assert!(check.burst_complete(4) && check.burst_complete(5));
        assert!(!check.burst_complete(6));
    }
}
