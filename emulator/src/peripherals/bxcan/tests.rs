//! The bxCAN model tested against RM0090 32's statements, one test per statement.

use super::*;

/// PCLK1 at 42 MHz, as on a 168 MHz F405 (any frequency would do).
const CLOCKS: Clocks = Clocks {
    sysclk: 168_000_000,
    hclk: 168_000_000,
    pclk1: 42_000_000,
    pclk2: 84_000_000,
};

/// BRP = 2 (3 cycles a quantum), TS1 = 10 (11 quanta), TS2 = 1 (2 quanta): 14 quanta, 42
/// cycles of 42 MHz, one microsecond a bit.
const BTR_1_MBIT: u32 = 2 | (10 << 16) | (1 << 20);
const BIT: Nanos = 1_000;

const MCR: u32 = 0x000;
const MSR: u32 = 0x004;
const TSR: u32 = 0x008;
const RF0R: u32 = 0x00C;
const RF1R: u32 = 0x010;
const IER: u32 = 0x014;
const ESR: u32 = 0x018;
const BTR: u32 = 0x01C;
const RI0R: u32 = 0x1B0;
const RDT0R: u32 = 0x1B4;
const RDL0R: u32 = 0x1B8;
const RI1R: u32 = 0x1C0;
const RDT1R: u32 = 0x1C4;
const FMR: u32 = 0x200;
const FM1R: u32 = 0x204;
const FS1R: u32 = 0x20C;
const FFA1R: u32 = 0x214;
const FA1R: u32 = 0x21C;

fn fr(bank: u32, register: u32) -> u32 {
    0x240 + 8 * bank + 4 * (register - 1)
}

fn ti(mailbox: u32) -> u32 {
    0x180 + 0x10 * mailbox
}

fn tdt(mailbox: u32) -> u32 {
    0x184 + 0x10 * mailbox
}

fn tdl(mailbox: u32) -> u32 {
    0x188 + 0x10 * mailbox
}

/// CAN_TIxR for a standard identifier.
fn standard(id: u32) -> u32 {
    id << 21
}

/// CAN_TIxR for an extended identifier.
fn extended(id: u32) -> u32 {
    (id << 3) | (1 << 2)
}

struct Bench {
    can: Can,
    now: Nanos,
}

impl Bench {
    fn new() -> Bench {
        Bench {
            can: Can::new(),
            now: 0,
        }
    }

    fn ctx(&self) -> Context {
        Context {
            now: self.now,
            clocks: CLOCKS,
        }
    }

    fn read(&mut self, offset: u32) -> u32 {
        let ctx = self.ctx();
        self.can.read(&ctx, offset, 4).expect("a modelled register")
    }

    fn write(&mut self, offset: u32, value: u32) {
        let ctx = self.ctx();
        self.can
            .write(&ctx, offset, 4, value)
            .expect("a modelled register");
    }

    fn wait(&mut self, duration: Nanos) {
        self.now += duration;
        let ctx = self.ctx();
        self.can.advance(&ctx);
    }

    /// Initialization mode, 1 Mbit/s, `btr_extra` (LBKM, SILM), then normal mode after the
    /// 11 recessive bits; bank 0 as one 32-bit mask filter accepting everything into FIFO 0.
    fn normal_with(btr_extra: u32, mcr_extra: u32) -> Bench {
        let mut bench = Bench::new();
        bench.write(MCR, mcr::INRQ | mcr_extra);
        bench.write(BTR, BTR_1_MBIT | btr_extra);
        bench.write(FMR, 14 << 8 | 1);
        bench.write(FS1R, 1);
        bench.write(fr(0, 1), 0);
        bench.write(fr(0, 2), 0);
        bench.write(FA1R, 1);
        bench.write(FMR, 14 << 8);
        bench.write(MCR, mcr_extra);
        bench.wait(11 * BIT);
        assert_eq!(bench.can.mode(), Mode::Normal);
        bench
    }

    fn normal() -> Bench {
        Bench::normal_with(0, 0)
    }

    /// Requests mailbox `mailbox` with identifier register `identifier` and one data byte.
    fn request(&mut self, mailbox: u32, identifier: u32, byte: u8) {
        self.write(tdt(mailbox), 1);
        self.write(tdl(mailbox), u32::from(byte));
        self.write(ti(mailbox), identifier | 1);
    }

    /// The bus takes the offered frame and reports success.
    fn send(&mut self) -> Frame {
        let frame = self
            .can
            .start_transmission(self.now)
            .expect("a frame offered");
        self.now += self.can.frame_duration(&frame);
        self.can.transmitted(self.now);
        frame
    }

    /// Filter configuration in filter initialization mode.
    fn filters(&mut self, configure: impl FnOnce(&mut Bench)) {
        self.write(FMR, 14 << 8 | 1);
        self.write(FA1R, 0);
        self.write(FS1R, 0);
        self.write(FM1R, 0);
        self.write(FFA1R, 0);
        configure(self);
        self.write(FMR, 14 << 8);
    }
}

fn data(id: Identifier, byte: u8) -> Frame {
    Frame::data(id, &[byte])
}

// --- 32.4 operating modes -------------------------------------------------------------

#[test]
fn rm0090_32_4_after_reset_the_controller_is_in_sleep_mode() {
    let mut bench = Bench::new();
    assert_eq!(bench.read(MCR), 0x0001_0002);
    assert_eq!(bench.read(MSR), 0x0000_0C02);
    assert_eq!(bench.read(TSR), 0x1C00_0000);
    assert_eq!(bench.read(BTR), 0x0123_0000);
    assert_eq!(bench.read(FMR), 0x2A1C_0E01);
}

#[test]
fn rm0090_32_4_1_inrq_enters_initialization_mode_and_sets_inak() {
    let mut bench = Bench::new();
    bench.write(MCR, mcr::INRQ);
    assert_eq!(bench.read(MSR) & 0b11, 0b01, "INAK set, SLAK cleared");
    assert_eq!(bench.can.mode(), Mode::Initialization);
}

#[test]
fn rm0090_32_4_1_leaving_initialization_waits_for_11_recessive_bits() {
    let mut bench = Bench::new();
    bench.write(MCR, mcr::INRQ);
    bench.write(BTR, BTR_1_MBIT);
    bench.write(MCR, 0);
    bench.wait(11 * BIT - 1);
    assert_eq!(bench.read(MSR) & 1, 1, "INAK still set before 11 bits");
    bench.wait(1);
    assert_eq!(bench.read(MSR) & 1, 0, "INAK cleared after 11 bits");
    assert_eq!(bench.can.mode(), Mode::Normal);
}

#[test]
fn rm0090_32_4_1_initialization_request_waits_for_the_end_of_a_transmission() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x123), 1);
    bench.can.start_transmission(bench.now);
    bench.write(MCR, mcr::INRQ);
    assert_eq!(bench.read(MSR) & 1, 0, "still transmitting");
    bench.can.transmitted(bench.now + 100 * BIT);
    assert_eq!(bench.read(MSR) & 1, 1);
}

#[test]
fn rm0090_32_9_2_btr_is_written_only_in_initialization_mode() {
    let mut bench = Bench::normal();
    bench.write(BTR, 0);
    assert_eq!(bench.read(BTR), BTR_1_MBIT);
    bench.write(MCR, mcr::INRQ);
    bench.write(BTR, 0);
    assert_eq!(bench.read(BTR), 0);
}

#[test]
fn rm0090_32_4_3_sleep_request_sets_slak_and_slaki_with_its_interrupt() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::SLKIE);
    bench.write(MCR, mcr::SLEEP);
    assert_eq!(bench.read(MSR) & 0b1_0011, 0b1_0010, "SLAK and SLAKI");
    assert!(bench.can.interrupt(IRQ_SCE));
    bench.write(MSR, 1 << 4);
    assert!(!bench.can.interrupt(IRQ_SCE), "SLAKI cleared by writing 1");
}

#[test]
fn rm0090_32_4_3_bus_activity_in_sleep_sets_wkui_and_awum_wakes_up() {
    let mut bench = Bench::new();
    bench.write(MCR, mcr::SLEEP | mcr::AWUM);
    bench.write(IER, ier::WKUIE);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now + 50 * BIT);
    bench.now += 50 * BIT;
    assert_eq!(bench.read(MSR) & (1 << 3), 1 << 3, "WKUI");
    assert!(bench.can.interrupt(IRQ_SCE));
    assert_eq!(
        bench.read(MCR) & mcr::SLEEP,
        0,
        "AWUM: SLEEP cleared by hardware"
    );
    // The reset BTR: BRP 0, TS1 3, TS2 2: 1 + 4 + 3 = 8 cycles of 42 MHz a bit.
    bench.wait(Clocks::nanos(11 * 8, CLOCKS.pclk1));
    assert_eq!(bench.can.mode(), Mode::Normal);
    assert_eq!(bench.read(RF0R) & 3, 0, "the waking frame is not received");
}

#[test]
fn rm0090_32_4_3_without_awum_bus_activity_leaves_the_controller_asleep() {
    let mut bench = Bench::new();
    bench.can.deliver(&data(Identifier::Standard(1), 0), 10);
    bench.wait(1_000_000);
    assert_eq!(bench.can.mode(), Mode::Sleep);
    assert_eq!(bench.read(MSR) & (1 << 3), 1 << 3, "WKUI set all the same");
}

#[test]
fn rm0090_32_9_2_reset_bit_forces_a_master_reset_into_sleep_mode() {
    let mut bench = Bench::normal();
    bench.request(0, standard(1), 0);
    bench.write(MCR, mcr::RESET);
    assert_eq!(bench.can.mode(), Mode::Sleep);
    assert_eq!(bench.read(MCR), 0x0001_0002);
    assert_eq!(bench.read(TSR), 0x1C00_0000);
    assert_eq!(bench.read(FA1R), 1, "the filters keep their configuration");
}

// --- 32.7.1 transmission --------------------------------------------------------------

#[test]
fn rm0090_32_7_1_transmit_request_is_offered_and_completion_sets_rqcp_txok_tme() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::TMEIE);
    bench.request(0, standard(0x123), 0xAB);
    assert_eq!(bench.read(TSR) & (1 << 26), 0, "TME0 cleared while pending");
    assert_eq!(bench.read(ti(0)) & 1, 1, "TXRQ reads 1 while pending");
    let offered = bench.can.offer().expect("offered");
    assert_eq!(offered, data(Identifier::Standard(0x123), 0xAB));
    let sent = bench.send();
    assert_eq!(sent, offered);
    let tsr = bench.read(TSR);
    assert_eq!(tsr & 0b11, 0b11, "RQCP0 and TXOK0");
    assert_ne!(tsr & (1 << 26), 0, "TME0 again");
    assert_eq!(bench.read(ti(0)) & 1, 0, "TXRQ cleared");
    assert!(bench.can.interrupt(IRQ_TX));
    bench.write(TSR, 1);
    assert!(!bench.can.interrupt(IRQ_TX));
}

#[test]
fn rm0090_32_7_1_the_lowest_identifier_is_sent_first() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x300), 0);
    bench.request(1, standard(0x100), 1);
    bench.request(2, extended(0x200 << 18), 2);
    assert_eq!(bench.send().id, Identifier::Standard(0x100));
    assert_eq!(bench.send().id, Identifier::Extended(0x200 << 18));
    assert_eq!(bench.send().id, Identifier::Standard(0x300));
}

#[test]
fn rm0090_32_7_1_equal_identifiers_go_by_the_lower_mailbox_number() {
    let mut bench = Bench::normal();
    bench.request(2, standard(0x100), 2);
    bench.request(1, standard(0x100), 1);
    assert_eq!(bench.send().data[0], 1);
    assert_eq!(bench.send().data[0], 2);
}

#[test]
fn rm0090_32_7_1_txfp_sends_in_request_order() {
    let mut bench = Bench::normal_with(0, mcr::TXFP);
    bench.request(2, standard(0x300), 0);
    bench.request(0, standard(0x200), 1);
    bench.request(1, standard(0x100), 2);
    assert_eq!(bench.send().id, Identifier::Standard(0x300));
    assert_eq!(bench.send().id, Identifier::Standard(0x200));
    assert_eq!(bench.send().id, Identifier::Standard(0x100));
}

#[test]
fn rm0090_32_7_1_abort_of_a_pending_mailbox_empties_it_at_once() {
    let mut bench = Bench::normal();
    bench.request(1, standard(0x100), 0);
    bench.write(TSR, 1 << 15);
    let tsr = bench.read(TSR);
    assert_ne!(tsr & (1 << 27), 0, "TME1");
    assert_eq!((tsr >> 8) & 0b11, 0b01, "RQCP1 set, TXOK1 cleared");
    assert_eq!(tsr & (1 << 15), 0, "ABRQ1 cleared by hardware");
    assert_eq!(bench.can.offer(), None);
}

#[test]
fn rm0090_32_7_1_abort_during_transmission_ends_with_the_transmission() {
    // Successful end: the mailbox empties with TXOK set.
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.write(TSR, 1 << 7);
    assert_ne!(bench.read(TSR) & (1 << 7), 0, "ABRQ0 set until the end");
    bench.can.transmitted(bench.now + 60 * BIT);
    assert_eq!(bench.read(TSR) & 0b11, 0b11);
    // Failed end: the mailbox empties with TXOK cleared, no retransmission.
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.write(TSR, 1 << 7);
    bench.can.lost_arbitration(bench.now + 5 * BIT);
    let tsr = bench.read(TSR);
    assert_eq!(tsr & 0b111, 0b101, "RQCP0 and ALST0, not TXOK0");
    assert_ne!(tsr & (1 << 26), 0);
    assert_eq!(bench.can.offer(), None);
}

#[test]
fn rm0090_32_7_1_lost_arbitration_is_retried_automatically() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.can.lost_arbitration(bench.now + 5 * BIT);
    let tsr = bench.read(TSR);
    assert_eq!(tsr & 0b1111, 0b0100, "ALST0 set, no RQCP0");
    assert_eq!(tsr & (1 << 26), 0, "still pending");
    assert!(bench.can.offer().is_some());
}

#[test]
fn rm0090_32_9_2_nart_transmits_once_whatever_the_result() {
    let mut bench = Bench::normal_with(0, mcr::NART);
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench
        .can
        .error(BusError::Acknowledgment, bench.now + 60 * BIT);
    let tsr = bench.read(TSR);
    assert_eq!(tsr & 0b1111, 0b1001, "RQCP0 and TERR0, not TXOK0");
    assert_ne!(tsr & (1 << 26), 0, "empty");
    assert_eq!(bench.can.offer(), None);
}

#[test]
fn rm0090_32_9_2_writing_rqcp_clears_txok_alst_and_terr() {
    let mut bench = Bench::normal_with(0, mcr::NART);
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.can.error(BusError::Stuff, bench.now + 10 * BIT);
    assert_ne!(bench.read(TSR) & 0b1111, 0);
    bench.write(TSR, 1);
    assert_eq!(bench.read(TSR) & 0b1111, 0);
}

#[test]
fn rm0090_32_9_2_code_names_the_next_free_mailbox_or_the_lowest_priority_one() {
    let mut bench = Bench::normal();
    assert_eq!((bench.read(TSR) >> 24) & 3, 0);
    bench.request(0, standard(0x100), 0);
    assert_eq!((bench.read(TSR) >> 24) & 3, 1);
    bench.request(1, standard(0x300), 0);
    let tsr = bench.read(TSR);
    assert_eq!((tsr >> 24) & 3, 2);
    assert_eq!(
        (tsr >> 29) & 7,
        0b010,
        "LOW1: mailbox 1 has the lowest priority"
    );
    bench.request(2, standard(0x200), 0);
    let tsr = bench.read(TSR);
    assert_eq!(
        (tsr >> 24) & 3,
        1,
        "all pending: CODE is the lowest-priority mailbox"
    );
    assert_eq!((tsr >> 29) & 7, 0b010);
}

#[test]
fn rm0090_32_9_3_mailbox_registers_are_write_protected_while_pending() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0x11);
    bench.write(tdl(0), 0x22);
    bench.write(ti(0), standard(0x7FF) | 1);
    assert_eq!(bench.read(tdl(0)), 0x11);
    assert_eq!(bench.send(), data(Identifier::Standard(0x100), 0x11));
}

#[test]
fn rm0090_32_4_2_no_transmission_outside_normal_mode() {
    let mut bench = Bench::new();
    bench.write(MCR, mcr::INRQ);
    bench.request(0, standard(0x100), 0);
    assert_eq!(bench.can.offer(), None, "initialization mode");
    bench.write(MCR, 0);
    assert_eq!(bench.can.offer(), None, "not yet synchronised");
    bench.wait(11 * 8 * 30);
    assert!(bench.can.offer().is_some());
}

// --- 32.7.3 reception and FIFOs --------------------------------------------------------

#[test]
fn rm0090_32_7_3_a_received_frame_is_pending_until_released_by_rfom() {
    let mut bench = Bench::normal();
    bench.can.deliver(
        &Frame::data(Identifier::Extended(0x1234_5678), &[1, 2, 3]),
        bench.now,
    );
    assert_eq!(bench.read(RF0R) & 3, 1, "FMP0 = 1");
    assert_eq!(bench.read(RI0R), (0x1234_5678 << 3) | (1 << 2));
    assert_eq!(bench.read(RDT0R) & 0xF, 3, "DLC");
    assert_eq!(bench.read(RDL0R), 0x0003_0201);
    bench.write(RF0R, 1 << 5);
    assert_eq!(bench.read(RF0R) & 0b10_0011, 0, "released, RFOM cleared");
}

#[test]
fn rm0090_32_7_3_fifo_keeps_arrival_order() {
    let mut bench = Bench::normal();
    for byte in 1..=3 {
        bench
            .can
            .deliver(&data(Identifier::Standard(0x10), byte), bench.now);
    }
    for byte in 1..=3u32 {
        assert_eq!(bench.read(RDL0R), byte);
        bench.write(RF0R, 1 << 5);
    }
}

#[test]
fn rm0090_32_7_3_the_third_message_sets_full() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::FFIE0);
    for byte in 0..2 {
        bench
            .can
            .deliver(&data(Identifier::Standard(1), byte), bench.now);
    }
    assert_eq!(bench.read(RF0R) & (1 << 3), 0);
    assert!(!bench.can.interrupt(IRQ_RX0));
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 2), bench.now);
    assert_eq!(bench.read(RF0R) & 0b1011, 0b1011, "FMP0 = 3 and FULL0");
    assert!(bench.can.interrupt(IRQ_RX0));
    bench.write(RF0R, 1 << 3);
    assert_eq!(bench.read(RF0R) & (1 << 3), 0, "FULL0 cleared by writing 1");
}

#[test]
fn rm0090_32_7_3_overrun_without_lock_overwrites_the_last_message() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::FOVIE0);
    for byte in 1..=4 {
        bench
            .can
            .deliver(&data(Identifier::Standard(1), byte), bench.now);
    }
    assert_ne!(bench.read(RF0R) & (1 << 4), 0, "FOVR0");
    assert!(bench.can.interrupt(IRQ_RX0));
    let mut bytes = Vec::new();
    for _ in 0..3 {
        bytes.push(bench.read(RDL0R));
        bench.write(RF0R, 1 << 5);
    }
    assert_eq!(bytes, [1, 2, 4]);
}

#[test]
fn rm0090_32_7_3_overrun_with_lock_discards_the_new_message() {
    let mut bench = Bench::normal_with(0, mcr::RFLM);
    for byte in 1..=4 {
        bench
            .can
            .deliver(&data(Identifier::Standard(1), byte), bench.now);
    }
    assert_ne!(bench.read(RF0R) & (1 << 4), 0, "FOVR0");
    let mut bytes = Vec::new();
    for _ in 0..3 {
        bytes.push(bench.read(RDL0R));
        bench.write(RF0R, 1 << 5);
    }
    assert_eq!(bytes, [1, 2, 3]);
    bench.write(RF0R, 1 << 4);
    assert_eq!(bench.read(RF0R) & (1 << 4), 0, "FOVR0 cleared by writing 1");
}

#[test]
fn rm0090_32_8_fifo_message_pending_interrupt_follows_fmp() {
    let mut bench = Bench::normal();
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert!(!bench.can.interrupt(IRQ_RX0), "FMPIE0 clear");
    bench.write(IER, ier::FMPIE0);
    assert!(bench.can.interrupt(IRQ_RX0));
    bench.write(RF0R, 1 << 5);
    assert!(!bench.can.interrupt(IRQ_RX0));
}

#[test]
fn rm0090_32_7_3_release_of_an_empty_fifo_has_no_effect() {
    let mut bench = Bench::normal();
    bench.write(RF0R, 1 << 5);
    assert_eq!(bench.read(RF0R), 0);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 7), bench.now);
    assert_eq!(bench.read(RDL0R), 7);
}

// --- 32.7.4 filters -----------------------------------------------------------------

fn image32_standard(id: u32) -> u32 {
    id << 21
}

fn image16_standard(id: u32) -> u32 {
    id << 5
}

#[test]
fn rm0090_32_7_4_identifier_mask_mode_32_bit() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FS1R, 1);
        bench.write(FM1R, 0);
        bench.write(fr(0, 1), image32_standard(0x120));
        // Compare STID[10:4] and IDE; STID[3:0] free.
        bench.write(fr(0, 2), image32_standard(0x7F0) | (1 << 2));
        bench.write(FA1R, 1);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x12F), 1), bench.now);
    bench
        .can
        .deliver(&data(Identifier::Standard(0x130), 2), bench.now);
    bench
        .can
        .deliver(&data(Identifier::Extended(0x120 << 18), 3), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 1);
    assert_eq!(bench.read(RDL0R), 1);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 0, "FMI 0");
}

#[test]
fn rm0090_32_7_4_identifier_list_mode_32_bit() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FS1R, 1);
        bench.write(FM1R, 1);
        bench.write(fr(0, 1), image32_standard(0x100));
        bench.write(fr(0, 2), (0x1ABC_DEF0 << 3) | (1 << 2));
        bench.write(FA1R, 1);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x101), 0), bench.now);
    bench
        .can
        .deliver(&data(Identifier::Extended(0x1ABC_DEF0), 1), bench.now);
    bench
        .can
        .deliver(&data(Identifier::Standard(0x100), 2), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 2);
    assert_eq!(bench.read(RDL0R), 1);
    assert_eq!(
        (bench.read(RDT0R) >> 8) & 0xFF,
        1,
        "FMI 1: the bank's second identifier"
    );
    bench.write(RF0R, 1 << 5);
    assert_eq!(bench.read(RDL0R), 2);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 0);
}

#[test]
fn rm0090_32_7_4_identifier_mask_mode_16_bit() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        // Filter 0: 0x200..0x20F (mask STID[10:4]); filter 1: exactly 0x300 data frames.
        bench.write(
            fr(0, 1),
            (image16_standard(0x7F0) << 16) | image16_standard(0x200),
        );
        bench.write(
            fr(0, 2),
            ((image16_standard(0x7FF) | (1 << 4) | (1 << 3)) << 16) | image16_standard(0x300),
        );
        bench.write(FA1R, 1);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x20A), 1), bench.now);
    bench
        .can
        .deliver(&Frame::remote(Identifier::Standard(0x300), 0), bench.now);
    bench
        .can
        .deliver(&data(Identifier::Standard(0x300), 2), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 2);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 0);
    bench.write(RF0R, 1 << 5);
    assert_eq!(bench.read(RDL0R), 2);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 1);
}

#[test]
fn rm0090_32_7_4_identifier_list_mode_16_bit() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FM1R, 1);
        bench.write(
            fr(0, 1),
            (image16_standard(0x011) << 16) | image16_standard(0x010),
        );
        bench.write(
            fr(0, 2),
            (image16_standard(0x013) << 16) | image16_standard(0x012),
        );
        bench.write(FA1R, 1);
    });
    for id in [0x013u16, 0x014, 0x010, 0x012, 0x011] {
        bench
            .can
            .deliver(&data(Identifier::Standard(id), id as u8), bench.now);
    }
    // FIFO holds three: 0x013 (filter 3), 0x010 (filter 0), 0x012 (filter 2); 0x014 is
    // discarded; 0x011 overwrites the last one (no lock): filter 1.
    let mut seen = Vec::new();
    for _ in 0..3 {
        seen.push((bench.read(RDL0R), (bench.read(RDT0R) >> 8) & 0xFF));
        bench.write(RF0R, 1 << 5);
    }
    assert_eq!(seen, [(0x13, 3), (0x10, 0), (0x11, 1)]);
}

/// RM0090 32.7.4, "Example of filter numbering" figure: banks, modes, FIFOs and the first
/// filter number of each bank.
#[test]
fn rm0090_32_7_4_filter_numbering_follows_the_manuals_example() {
    // (bank, 32-bit, list, FIFO 1, active, first number)
    let layout = [
        (0, true, true, false, true, 0),
        (1, true, false, false, true, 2),
        (2, false, false, true, true, 0),
        (3, false, true, false, true, 3),
        (4, true, true, true, true, 2),
        (5, true, true, false, false, 7),
        (6, false, false, false, true, 9),
        (7, false, false, true, false, 4),
        (8, false, true, true, true, 6),
        (9, true, true, false, true, 11),
        (10, true, true, true, false, 10),
        (11, true, true, true, true, 12),
        (12, true, false, true, true, 14),
        (13, true, false, false, true, 13),
    ];
    let mut banks = FilterBanks::new();
    let (mut scale, mut mode, mut fifo, mut active) = (0, 0, 0, 0);
    for (bank, wide, list, fifo1, on, _) in layout {
        scale |= u32::from(wide) << bank;
        mode |= u32::from(list) << bank;
        fifo |= u32::from(fifo1) << bank;
        active |= u32::from(on) << bank;
    }
    assert!(banks.write(FS1R, scale));
    assert!(banks.write(FM1R, mode));
    assert!(banks.write(FFA1R, fifo));
    assert!(banks.write(FA1R, active));
    let firsts = banks.first_numbers();
    for (bank, .., first) in layout {
        assert_eq!(firsts[bank], first, "bank {bank}");
    }
}

#[test]
fn rm0090_32_7_4_deactivated_banks_keep_their_numbers_but_do_not_match() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        // Bank 0: 32-bit list, inactive (filters 0 and 1); bank 1: 32-bit mask, all.
        bench.write(FS1R, 0b11);
        bench.write(FM1R, 0b01);
        bench.write(fr(0, 1), image32_standard(0x55));
        bench.write(fr(1, 1), 0);
        bench.write(fr(1, 2), 0);
        bench.write(FA1R, 0b10);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x55), 0), bench.now);
    assert_eq!(
        (bench.read(RDT0R) >> 8) & 0xFF,
        2,
        "bank 1's filter is number 2"
    );
}

#[test]
fn rm0090_32_7_4_a_32_bit_filter_takes_priority_over_a_16_bit_filter() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        // Bank 0: 16-bit list with 0x42 (filter 0); bank 1: 32-bit mask, all (filter 4).
        bench.write(FS1R, 0b10);
        bench.write(FM1R, 0b01);
        bench.write(fr(0, 1), image16_standard(0x42) * 0x1_0001);
        bench.write(fr(0, 2), image16_standard(0x42) * 0x1_0001);
        bench.write(fr(1, 1), 0);
        bench.write(fr(1, 2), 0);
        bench.write(FA1R, 0b11);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x42), 0), bench.now);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 4);
}

#[test]
fn rm0090_32_7_4_list_mode_takes_priority_over_mask_mode_of_equal_scale() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        // Bank 0: 32-bit mask, all (filter 0); bank 1: 32-bit list with 0x42 (filters 1, 2).
        bench.write(FS1R, 0b11);
        bench.write(FM1R, 0b10);
        bench.write(fr(0, 1), 0);
        bench.write(fr(0, 2), 0);
        bench.write(fr(1, 1), image32_standard(0x41));
        bench.write(fr(1, 2), image32_standard(0x42));
        bench.write(FA1R, 0b11);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x42), 0), bench.now);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 2);
}

#[test]
fn rm0090_32_7_4_equal_scale_and_mode_go_by_the_lower_filter_number() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FS1R, 0b11);
        for bank in 0..2 {
            bench.write(fr(bank, 1), 0);
            bench.write(fr(bank, 2), 0);
        }
        bench.write(FA1R, 0b11);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x42), 0), bench.now);
    assert_eq!((bench.read(RDT0R) >> 8) & 0xFF, 0);
}

#[test]
fn rm0090_32_7_4_ffa1r_assigns_a_bank_to_fifo_1() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::FMPIE0 << 3);
    bench.filters(|bench| {
        bench.write(FS1R, 0b11);
        bench.write(FFA1R, 0b10);
        bench.write(fr(0, 1), image32_standard(0x10));
        bench.write(fr(0, 2), image32_standard(0x7FF));
        bench.write(fr(1, 1), image32_standard(0x20));
        bench.write(fr(1, 2), image32_standard(0x7FF));
        bench.write(FA1R, 0b11);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x20), 5), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 0);
    assert_eq!(bench.read(RF1R) & 3, 1);
    assert_eq!(bench.read(RI1R), image32_standard(0x20));
    assert_eq!((bench.read(RDT1R) >> 8) & 0xFF, 0, "FIFO 1 numbers from 0");
    assert!(bench.can.interrupt(IRQ_RX1));
    assert!(!bench.can.interrupt(IRQ_RX0));
}

#[test]
fn rm0090_32_7_4_a_frame_no_filter_accepts_is_discarded() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FS1R, 1);
        bench.write(FM1R, 1);
        bench.write(fr(0, 1), image32_standard(0x10));
        bench.write(fr(0, 2), image32_standard(0x11));
        bench.write(FA1R, 1);
    });
    bench
        .can
        .deliver(&data(Identifier::Standard(0x12), 0), bench.now);
    assert_eq!(bench.read(RF0R), 0);
    assert_eq!(bench.read(RF1R), 0);
}

#[test]
fn rm0090_32_9_4_filter_mode_scale_and_fifo_are_written_only_in_filter_initialization() {
    let mut bench = Bench::normal();
    bench.write(FM1R, 0xFF);
    bench.write(FS1R, 0xFF);
    bench.write(FFA1R, 0xFF);
    assert_eq!(bench.read(FM1R), 0);
    assert_eq!(bench.read(FS1R), 1);
    assert_eq!(bench.read(FFA1R), 0);
}

#[test]
fn rm0090_32_9_4_an_active_banks_registers_are_protected_outside_filter_initialization() {
    let mut bench = Bench::normal();
    bench.write(fr(0, 1), 0x1234_5678);
    assert_eq!(bench.read(fr(0, 1)), 0, "bank 0 active");
    bench.write(fr(1, 1), 0x1234_5678);
    assert_eq!(bench.read(fr(1, 1)), 0x1234_5678, "bank 1 inactive");
}

#[test]
fn rm0090_32_9_4_filter_initialization_mode_stops_acceptance() {
    let mut bench = Bench::normal();
    bench.write(FMR, 14 << 8 | 1);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(RF0R), 0);
}

#[test]
fn rm0090_32_9_4_banks_from_can2sb_on_belong_to_can2() {
    let mut bench = Bench::normal();
    bench.filters(|bench| {
        bench.write(FS1R, 1 << 5);
        bench.write(fr(5, 1), 0);
        bench.write(fr(5, 2), 0);
        bench.write(FA1R, 1 << 5);
    });
    bench.write(FMR, 5 << 8);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(RF0R), 0, "bank 5 is CAN2's");
    bench.write(FMR, 6 << 8);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(RF0R), 1, "bank 5 is CAN1's");
}

// --- 32.5 test modes ----------------------------------------------------------------

#[test]
fn rm0090_32_5_2_loop_back_mode_receives_its_own_frames_and_ignores_can_rx() {
    let mut bench = Bench::normal_with(btr::LBKM, 0);
    bench.request(0, standard(0x321), 9);
    assert_eq!(bench.can.offer(), None, "the bus model does not carry it");
    let frame = data(Identifier::Standard(0x321), 9);
    let end = bench.now + bench.can.frame_duration(&frame);
    assert_eq!(bench.can.next_event(&bench.ctx()), Some(end));
    bench.wait(end - bench.now);
    assert_eq!(bench.read(TSR) & 0b11, 0b11);
    assert_eq!(bench.read(RF0R) & 3, 1);
    assert_eq!(bench.read(RI0R), image32_standard(0x321));
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 1, "CAN_RX is disregarded");
}

#[test]
fn rm0090_32_5_1_silent_mode_receives_but_starts_no_transmission() {
    let mut bench = Bench::normal_with(btr::SILM, 0);
    bench.request(0, standard(0x100), 0);
    assert_eq!(bench.can.offer(), None);
    assert_eq!(bench.can.start_transmission(bench.now), None);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(RF0R) & 3, 1);
}

#[test]
fn rm0090_32_5_3_loop_back_combined_with_silent_mode_is_a_closed_self_test() {
    let mut bench = Bench::normal_with(btr::LBKM | btr::SILM, 0);
    bench.request(0, standard(0x100), 1);
    bench.request(1, standard(0x080), 2);
    assert_eq!(bench.can.offer(), None);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    bench.wait(1_000 * BIT);
    let mut bytes = Vec::new();
    while bench.read(RF0R) & 3 != 0 {
        bytes.push(bench.read(RDL0R));
        bench.write(RF0R, 1 << 5);
    }
    // The first request starts at once; nothing comes from CAN_RX.
    assert_eq!(bytes, [1, 2]);
}

// --- 32.7.6 error management --------------------------------------------------------

#[test]
fn rm0090_32_7_6_a_transmit_error_adds_8_to_tec_and_sets_lec() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.can.error(BusError::BitDominant, bench.now + 10 * BIT);
    let esr = bench.read(ESR);
    assert_eq!((esr >> 16) & 0xFF, 8);
    assert_eq!((esr >> 4) & 7, BusError::BitDominant as u32);
    assert_ne!(bench.read(TSR) & (1 << 3), 0, "TERR0");
    assert!(bench.can.offer().is_some(), "retransmitted");
}

#[test]
fn rm0090_32_7_6_a_successful_transfer_decrements_tec_and_clears_lec() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    bench.can.start_transmission(bench.now);
    bench.can.error(BusError::Form, bench.now + 10 * BIT);
    bench.send();
    let esr = bench.read(ESR);
    assert_eq!((esr >> 16) & 0xFF, 7);
    assert_eq!((esr >> 4) & 7, 0);
}

#[test]
fn rm0090_32_7_6_receive_errors_count_in_rec_and_a_reception_decrements_it() {
    let mut bench = Bench::normal();
    bench.can.receive_error(BusError::Crc, bench.now);
    bench.can.receive_error(BusError::Crc, bench.now);
    let esr = bench.read(ESR);
    assert_eq!(esr >> 24, 2);
    assert_eq!((esr >> 4) & 7, BusError::Crc as u32);
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    assert_eq!(bench.read(ESR) >> 24, 1);
}

#[test]
fn rm0090_32_7_6_error_warning_at_96_and_error_passive_above_127() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::ERRIE | ier::EPVIE);
    for count in 1..=17u32 {
        bench.can.receive_error(BusError::Stuff, bench.now);
        for _ in 0..7 {
            bench.can.receive_error(BusError::Stuff, bench.now);
        }
        let esr = bench.read(ESR);
        let rec = 8 * count;
        assert_eq!(esr >> 24, rec);
        assert_eq!(esr & 1, u32::from(rec >= 96), "EWGF at REC {rec}");
        assert_eq!((esr >> 1) & 1, u32::from(rec > 127), "EPVF at REC {rec}");
        assert_eq!(
            bench.can.interrupt(IRQ_SCE),
            rec > 127,
            "ERRI from EPVF at {rec}"
        );
    }
}

#[test]
fn rm0090_32_7_6_a_reception_above_127_brings_rec_back_to_the_error_active_range() {
    let mut bench = Bench::normal();
    for _ in 0..130 {
        bench.can.receive_error(BusError::Stuff, bench.now);
    }
    bench
        .can
        .deliver(&data(Identifier::Standard(1), 0), bench.now);
    let rec = bench.read(ESR) >> 24;
    assert!(
        (119..=127).contains(&rec),
        "ISO 11898-1: between 119 and 127, got {rec}"
    );
    assert_eq!(bench.read(ESR) & 2, 0);
}

#[test]
fn rm0090_32_7_6_an_error_passive_transmitter_does_not_count_ack_errors() {
    let mut bench = Bench::normal();
    bench.request(0, standard(0x100), 0);
    for _ in 0..16 {
        bench.can.start_transmission(bench.now);
        bench.can.error(BusError::Stuff, bench.now);
    }
    assert_eq!(bench.can.transmit_error_counter(), 128);
    bench.can.start_transmission(bench.now);
    bench.can.error(BusError::Acknowledgment, bench.now);
    assert_eq!(bench.can.transmit_error_counter(), 128);
}

/// Drives TEC above 255 with 32 transmit errors.
fn drive_bus_off(bench: &mut Bench) {
    bench.request(0, standard(0x100), 0);
    for _ in 0..32 {
        bench.can.start_transmission(bench.now);
        bench.can.error(BusError::BitRecessive, bench.now);
    }
}

#[test]
fn rm0090_32_7_6_tec_above_255_is_bus_off_and_stops_transmission() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::ERRIE | ier::BOFIE);
    drive_bus_off(&mut bench);
    assert_ne!(bench.read(ESR) & 4, 0, "BOFF");
    assert!(bench.can.is_bus_off());
    assert!(bench.can.interrupt(IRQ_SCE));
    assert_eq!(bench.can.offer(), None);
    assert_eq!(bench.read(TSR) & (1 << 26), 0, "the mailbox stays pending");
}

#[test]
fn rm0090_32_7_6_abom_leaves_bus_off_after_128_times_11_recessive_bits() {
    let mut bench = Bench::normal_with(0, mcr::ABOM);
    drive_bus_off(&mut bench);
    bench.wait(128 * 11 * BIT - 1);
    assert!(bench.can.is_bus_off());
    bench.wait(1);
    assert!(!bench.can.is_bus_off());
    assert_eq!(
        bench.read(ESR) & 0xFFFF_0007,
        0,
        "error active, counters cleared"
    );
    assert!(bench.can.offer().is_some());
}

#[test]
fn rm0090_32_7_6_without_abom_recovery_waits_for_inrq_set_and_cleared() {
    let mut bench = Bench::normal();
    drive_bus_off(&mut bench);
    bench.wait(10 * 128 * 11 * BIT);
    assert!(
        bench.can.is_bus_off(),
        "no recovery without the software's request"
    );
    bench.write(MCR, mcr::INRQ);
    bench.write(MCR, 0);
    bench.wait(11 * BIT);
    assert!(bench.can.is_bus_off());
    bench.wait(128 * 11 * BIT);
    assert!(!bench.can.is_bus_off());
}

#[test]
fn rm0090_32_9_2_erri_needs_an_enabled_condition_and_is_cleared_by_writing_1() {
    let mut bench = Bench::normal();
    bench.write(IER, ier::ERRIE);
    bench.can.receive_error(BusError::Form, bench.now);
    assert_eq!(bench.read(MSR) & (1 << 2), 0, "LECIE clear: no ERRI");
    bench.write(IER, ier::ERRIE | ier::LECIE);
    bench.can.receive_error(BusError::Form, bench.now);
    assert_ne!(bench.read(MSR) & (1 << 2), 0);
    assert!(bench.can.interrupt(IRQ_SCE));
    bench.write(MSR, 1 << 2);
    assert!(!bench.can.interrupt(IRQ_SCE));
}

// --- 32.7.7 bit timing, 32.9 register access -----------------------------------------

#[test]
fn rm0090_32_7_7_bit_time_is_brp_quanta_times_one_plus_ts1_plus_ts2() {
    let bench = Bench::normal();
    assert_eq!(bench.can.bit_time_cycles(), 3 * 14);
    assert_eq!(bench.can.bits_duration(1), BIT);
    let frame = data(Identifier::Standard(0x100), 0);
    assert_eq!(
        bench.can.frame_duration(&frame),
        u64::from(frame.bit_length()) * BIT
    );
}

#[test]
fn rm0090_32_9_registers_are_accessed_by_words_and_holes_are_refused() {
    let mut bench = Bench::new();
    let ctx = bench.ctx();
    assert!(matches!(
        bench.can.read(&ctx, MCR, 2),
        Err(AccessError::Width { size: 2, .. })
    ));
    assert!(matches!(
        bench.can.write(&ctx, 0x020, 4, 0),
        Err(AccessError::Unmodelled { offset: 0x020, .. })
    ));
    assert!(matches!(
        bench.can.read(&ctx, 0x208, 4),
        Err(AccessError::Unmodelled { offset: 0x208, .. })
    ));
    assert!(bench.read(fr(27, 2)) == 0);
    assert!(matches!(
        bench.can.read(&ctx, 0x320, 4),
        Err(AccessError::Unmodelled { .. })
    ));
}

#[test]
fn rm0090_table_61_can1_drives_interrupts_19_to_22() {
    assert_eq!(Can::new().interrupt_lines(), &[19, 20, 21, 22]);
}
