//! The CAN acceptance filters a channel needs, derived from its configuration, and their
//! layout in the bxCAN's filter banks.
//!
//! A channel follows exactly these identifiers (EN 50325-5 7.1, CiA 301 7.2): NMT 000h, GFC
//! 001h, its node's SDO requests 600h + node-ID, LSS requests 7E5h (CiA 305: both channels
//! run the LSS slave, `crate::lss`), and both COB-IDs of every configured SRDO,
//! transmit and receive (a channel sees its own node's SRDO frames: channel B builds the
//! inverted frame from channel A's plain one, channel A checks that the inverted one follows,
//! and both report a foreign sender on their identifiers). Every other frame is rejected by
//! the controller before it takes a place in a receive queue, so a busy bus, however loud,
//! cannot push a safety frame out of one.
//!
//! The protocol decides the filters, the driver only applies them ([`crate::channel_loop`]):
//! [`AcceptanceList::of`] is the one list, [`bank_layout`] its place in the bxCAN's banks
//! (RM0090 32.7.4), and [`AcceptanceList::accepts`] the same decision in software, which the
//! channel loop applies to every received frame on every board (the QEMU board layer, until
//! 2026-12-07, sent the same list to the hub, which applied it in the controller's place:
//! `emulation_wire::Wire::Accept`).

use heapless::Vec;
use shared::canopen::NodeId;
use shared::safety::config::SafetyConfig;
use shared::safety::types::{CobIdPair, SRDO_IDENTIFIERS};
use shared::{CanFrame, CanId};

/// NMT module control (CiA 301 7.2.8.3.1).
pub const NMT: u16 = 0x000;
/// Global failsafe command (EN 50325-5 7.2.1).
pub const GFC: u16 = 0x001;
/// The SDO request identifier of node-ID 0 (CiA 301 7.3.5: 600h + node-ID).
pub const SDO_REQUEST_BASE: u16 = 0x600;
/// LSS master to slave (CiA 305): the requests both channels' LSS slaves follow.
pub const LSS_REQUEST: u16 = shared::canopen::lss::MASTER_TO_SLAVE.raw();

/// The most SRDOs a node has (0x1301..=0x1340, EN 50325-5 Table 5).
pub const MAX_SRDOS: usize = 64;
/// The SimpleCAN identifiers a channel may accept besides (feature `simplecan`): the sync
/// and the SC-ID of every SDD entry the channels cross-check ([`crate::simplecan::ENTRIES`]).
#[cfg(feature = "simplecan")]
pub const SIMPLECAN_ACCEPTED: usize = 1 + crate::simplecan::ENTRIES;
/// The SimpleCAN identifiers a channel may accept besides: none without the feature
/// `simplecan`.
#[cfg(not(feature = "simplecan"))]
pub const SIMPLECAN_ACCEPTED: usize = 0;
/// The most identifiers a channel accepts: two per SRDO, NMT, GFC, SDO, LSS and the SimpleCAN
/// ones.
pub const MAX_ACCEPTED: usize = 2 * MAX_SRDOS + 4 + SIMPLECAN_ACCEPTED;

/// Filter banks CAN1 of the STM32F405 owns: the 28 banks are shared with CAN2, and the reset
/// value of CAN_FMR.CAN2SB (14), which the board keeps, gives CAN1 banks 0 to 13 (RM0090
/// 32.9.5).
pub const CAN1_BANKS: usize = 14;
/// Standard identifiers one bank holds in 16-bit list mode (RM0090 32.7.4, Figure 342).
pub const IDS_PER_LIST16_BANK: usize = 4;
/// Standard identifiers one bank holds in 32-bit list mode.
pub const IDS_PER_LIST32_BANK: usize = 2;

/// The identifiers a channel accepts, each once; data frames only (nothing this node follows
/// is a remote frame).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AcceptanceList {
    ids: Vec<CanId, MAX_ACCEPTED>,
}

impl AcceptanceList {
    /// The list for node `node_id` with `config`: NMT, GFC, SDO 600h + node-ID, LSS 7E5h and both
    /// COB-IDs of every SRDO that exists (direction not 0) and names a valid identifier pair.
    /// A record whose identifiers are not a valid pair cannot reach Operational (the
    /// Operational-entry check refuses it), so nothing is lost by not following them.
    pub fn of<const N: usize>(node_id: NodeId, config: &SafetyConfig<N>) -> Self {
        let mut ids: Vec<CanId, MAX_ACCEPTED> = Vec::new();
        let mut add = |raw: u16| {
            if let Ok(id) = CanId::new(raw) {
                if !ids.contains(&id) {
                    // At most 2 + 2 x 64 + 1 identifiers (the core refuses more than 64
                    // SRDOs): the list never fills.
                    let _ = ids.push(id);
                }
            }
        };
        add(NMT);
        add(GFC);
        for record in config.srdos.iter().filter(|record| record.exists()) {
            if let Ok(pair) = CobIdPair::new(record.cob_id_1, record.cob_id_2) {
                add(pair.first());
                add(pair.second());
            }
        }
        add(SDO_REQUEST_BASE + u16::from(node_id.raw()));
        add(LSS_REQUEST);
        AcceptanceList { ids }
    }

    /// The identifiers: NMT, GFC, the SRDO identifiers in the order of the records, SDO, LSS,
    /// then the SimpleCAN ones ([`AcceptanceList::add_simplecan`]).
    pub fn ids(&self) -> &[CanId] {
        &self.ids
    }

    /// Adds what the SimpleCAN layer `layer` follows (SC_REQ_12, SC_REQ_24): the sync 02Fh
    /// (its master's, and any other master's for the several-masters check) and the SC-ID of
    /// every SDD entry in use, consumed and produced (channel B checks channel A's packets on
    /// the bus, and both report another sender on the node's SC-IDs).
    #[cfg(feature = "simplecan")]
    pub fn add_simplecan(&mut self, layer: &crate::simplecan::Layer) {
        let sync = shared::simplecan::frame::SYNC_IDENTIFIER;
        let entries = layer.entries.get(..layer.count).unwrap_or(&layer.entries);
        let ids = core::iter::once(sync).chain(
            entries
                .iter()
                .filter_map(|entry| CanId::new(u16::from(entry.sc_id)).ok()),
        );
        for id in ids {
            if !self.ids.contains(&id) {
                // SIMPLECAN_ACCEPTED places beyond the SRDOs': the list never fills.
                let _ = self.ids.push(id);
            }
        }
    }

    /// `true` when the channel follows `frame`: a data frame on one of the identifiers.
    pub fn accepts(&self, frame: &CanFrame) -> bool {
        !frame.is_remote() && self.ids.contains(&frame.id())
    }
}

/// One bxCAN filter bank as this node uses it (RM0090 32.7.4), identifiers as 11-bit values,
/// data frames only (RTR = 0, IDE = 0 in every entry).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bank {
    /// 16-bit list mode: four identifiers, each accepted exactly (an unused place repeats
    /// one of the others).
    List16([u16; 4]),
    /// 16-bit mask mode: two (identifier, mask) pairs; a frame is accepted when its
    /// identifier equals the pair's on every bit set in the mask.
    Mask16([(u16, u16); 2]),
}

impl Bank {
    /// `true` when this bank accepts a frame with `id` and `remote`, as the controller
    /// decides it.
    pub fn accepts(&self, id: u16, remote: bool) -> bool {
        if remote {
            return false;
        }
        match self {
            Bank::List16(ids) => ids.contains(&id),
            Bank::Mask16(pairs) => pairs
                .iter()
                .any(|&(filter, mask)| (id ^ filter) & mask & 0x7FF == 0),
        }
    }
}

/// The receive FIFO a bank's frames go to (RM0090 32.7.4: CAN_FFA1R).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fifo {
    /// FIFO 0: the SRDO identifiers.
    Srdo,
    /// FIFO 1: NMT, GFC and SDO, so that a burst of SDO requests cannot fill the FIFO the
    /// SRDO frames wait in.
    Services,
}

/// The filter banks for an [`AcceptanceList`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BankLayout {
    /// The banks, from bank 0, each with the FIFO it feeds.
    pub banks: Vec<(Bank, Fifo), CAN1_BANKS>,
    /// `true` when the banks accept exactly the list; `false` for the fallback, which
    /// accepts the whole SRDO range 100h..=180h and leaves the exact choice to the software
    /// filter ([`AcceptanceList::accepts`]).
    pub exact: bool,
}

impl BankLayout {
    /// The FIFO a frame with `id` and `remote` goes to, `None` when the banks reject it.
    /// (Of two matching banks the controller takes the lower-numbered one, RM0090 32.7.4;
    /// here no identifier matches banks of both FIFOs.)
    pub fn fifo(&self, id: u16, remote: bool) -> Option<Fifo> {
        self.banks
            .iter()
            .find(|(bank, _)| bank.accepts(id, remote))
            .map(|&(_, fifo)| fifo)
    }

    /// `true` when a frame with `id` and `remote` passes the banks.
    pub fn accepts(&self, id: u16, remote: bool) -> bool {
        self.fifo(id, remote).is_some()
    }
}

/// Why no bank layout was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FilterError {
    /// Too few filter banks: not even the fallback (one mask bank for the SRDO range, one
    /// list bank for NMT, GFC and SDO) fits.
    TooFewBanks {
        /// The banks there are.
        banks: u8,
    },
}

/// The bank layout of `list` in `banks` filter banks: 16-bit list mode, four identifiers
/// per bank (56 in CAN1's 14 banks, where 32-bit list mode would hold only 28), the SRDO
/// identifiers in banks feeding FIFO 0 and NMT, GFC and SDO in one feeding FIFO 1, when they
/// fit; the controller then accepts exactly the list.
///
/// When they do not (more than 26 SRDOs in 14 banks), the fallback: one 16-bit mask bank
/// accepting 100h..=17Fh and 180h (the SRDO range, [`SRDO_IDENTIFIERS`],
/// and 100h, which nothing uses) and the list bank for NMT, GFC and SDO; the controller
/// then passes frames on SRDO identifiers the node does not use, which the software filter
/// drops. A babbler outside the SRDO range is still rejected by the controller. The layout
/// says which one it is ([`BankLayout::exact`]).
#[inline(never)]
pub fn bank_layout(list: &AcceptanceList, banks: usize) -> Result<BankLayout, FilterError> {
    let banks = banks.min(CAN1_BANKS);
    let too_few = FilterError::TooFewBanks {
        banks: u8::try_from(banks).unwrap_or(u8::MAX),
    };
    let in_range = |id: &u16| SRDO_IDENTIFIERS.contains(id);
    let ids = || list.ids().iter().map(|id| id.raw());
    let srdo = ids().filter(in_range).count();
    let services = list.ids().len() - srdo;
    let mut layout = BankLayout {
        banks: Vec::new(),
        exact: srdo.div_ceil(IDS_PER_LIST16_BANK) + services.div_ceil(IDS_PER_LIST16_BANK) <= banks,
    };
    if layout.exact {
        list16(ids().filter(in_range), Fifo::Srdo, &mut layout.banks).map_err(|()| too_few)?;
    } else {
        let range = Bank::Mask16([(0x100, 0x780), (*SRDO_IDENTIFIERS.end(), 0x7FF)]);
        layout
            .banks
            .push((range, Fifo::Srdo))
            .map_err(|_| too_few)?;
    }
    let others = ids().filter(|id| !in_range(id));
    list16(others, Fifo::Services, &mut layout.banks).map_err(|()| too_few)?;
    if layout.banks.len() > banks {
        return Err(too_few);
    }
    Ok(layout)
}

/// Appends `ids` four to a 16-bit list bank feeding `fifo`; the last bank's unused places
/// repeat its first identifier. `Err` when the banks run out.
fn list16(
    ids: impl Iterator<Item = u16>,
    fifo: Fifo,
    banks: &mut Vec<(Bank, Fifo), CAN1_BANKS>,
) -> Result<(), ()> {
    let mut entries = [0u16; IDS_PER_LIST16_BANK];
    let mut used = 0;
    for id in ids {
        if used == 0 {
            entries = [id; IDS_PER_LIST16_BANK];
        }
        entries[used] = id;
        used += 1;
        if used == IDS_PER_LIST16_BANK {
            banks.push((Bank::List16(entries), fifo)).map_err(|_| ())?;
            used = 0;
        }
    }
    if used > 0 {
        banks.push((Bank::List16(entries), fifo)).map_err(|_| ())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::safety::config::SrdoRecord;

    fn node(raw: u8) -> NodeId {
        NodeId::new(raw).unwrap()
    }

    /// A configuration with `count` receive SRDOs on 101h/102h, 103h/104h, ...
    fn config<const N: usize>(count: usize) -> SafetyConfig<N> {
        let mut config = SafetyConfig::<N>::predefined(1, &[], &[]);
        for (index, record) in config.srdos.iter_mut().enumerate() {
            *record = SrdoRecord::DELETED;
            if index < count {
                record.direction = 2;
                record.cob_id_1 = 0x101 + 2 * index as u32;
                record.cob_id_2 = 0x102 + 2 * index as u32;
            }
        }
        config
    }

    fn raw(list: &AcceptanceList) -> std::vec::Vec<u16> {
        list.ids().iter().map(|id| id.raw()).collect()
    }

    fn data(id: u16) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &[0]).unwrap()
    }

    /// EN 50325-5 7.1.1 (both frames received), 7.2.1, CiA 301 7.3.5, CiA 305: NMT, GFC, SDO
    /// 600h + node-ID, LSS 7E5h and both COB-IDs of each configured SRDO, and nothing else
    /// (not the LSS answers 7E4h of other nodes); a deleted SRDO adds nothing.
    #[test]
    fn en50325_5_7_1_1_a_channel_accepts_both_cob_ids_of_each_srdo_nmt_gfc_and_its_sdo_only() {
        let mut config = config::<4>(2);
        config.srdos[3].direction = 1;
        config.srdos[3].cob_id_1 = 0x141;
        config.srdos[3].cob_id_2 = 0x142;
        // Deleted, with identifiers left in it: not followed.
        config.srdos[2].cob_id_1 = 0x151;
        config.srdos[2].cob_id_2 = 0x152;
        let list = AcceptanceList::of(node(33), &config);
        assert_eq!(
            raw(&list),
            [
                0x000, 0x001, 0x101, 0x102, 0x103, 0x104, 0x141, 0x142, 0x621, 0x7E5
            ]
        );
        for id in [0x000, 0x001, 0x101, 0x104, 0x142, 0x621, 0x7E5] {
            assert!(list.accepts(&data(id)), "{id:#x}");
        }
        for id in [
            0x080, 0x0A1, 0x105, 0x151, 0x5A1, 0x601, 0x622, 0x701, 0x7E4, 0x7FF,
        ] {
            assert!(!list.accepts(&data(id)), "{id:#x}");
        }
        let remote = CanFrame::remote(CanId::new(0x101).unwrap(), 1).unwrap();
        assert!(!list.accepts(&remote), "remote frames are not followed");
    }

    /// A record whose identifiers are not a valid pair (outside 101h..=180h, or not odd and
    /// the next one) adds nothing: it cannot reach Operational.
    #[test]
    fn an_invalid_identifier_pair_is_not_followed() {
        let mut config = config::<2>(2);
        config.srdos[1].cob_id_1 = 0x181;
        config.srdos[1].cob_id_2 = 0x182;
        assert_eq!(
            raw(&AcceptanceList::of(node(1), &config)),
            [0x000, 0x001, 0x101, 0x102, 0x601, 0x7E5]
        );
    }

    /// The device's 4 SRDOs (11 identifiers) take three 16-bit list banks and are exact; the
    /// controller model accepts exactly the list.
    #[test]
    fn en50325_5_7_1_1_the_bank_layout_accepts_exactly_the_list() {
        let list = AcceptanceList::of(node(33), &config::<4>(4));
        let layout = bank_layout(&list, CAN1_BANKS).unwrap();
        assert!(layout.exact);
        // 8 SRDO identifiers in two banks, NMT, GFC, SDO and LSS in the third.
        assert_eq!(layout.banks.len(), 3);
        for id in 0..=0x7FF {
            assert_eq!(
                layout.accepts(id, false),
                list.accepts(&data(id)),
                "{id:#x}"
            );
            assert!(!layout.accepts(id, true));
        }
        for id in [0x101, 0x108] {
            assert_eq!(layout.fifo(id, false), Some(Fifo::Srdo));
        }
        for id in [0x000, 0x001, 0x621, 0x7E5] {
            assert_eq!(layout.fifo(id, false), Some(Fifo::Services));
        }
    }

    /// 14 banks hold 56 identifiers in 16-bit list mode, twice the 28 of 32-bit list mode;
    /// with the SRDO identifiers in banks of their own (FIFO 0), 26 SRDOs fit (52 in 13
    /// banks, NMT, GFC, SDO and LSS in the 14th), 27 do not. Beyond, the fallback: one mask
    /// bank for the SRDO range, NMT, GFC, SDO and LSS still exact, everything else rejected.
    #[test]
    fn sixteen_bit_list_mode_holds_56_identifiers_then_the_srdo_range_is_masked() {
        assert_eq!(IDS_PER_LIST16_BANK * CAN1_BANKS, 56);
        assert_eq!(IDS_PER_LIST32_BANK * CAN1_BANKS, 28);
        let fits = AcceptanceList::of(node(5), &config::<64>(26));
        assert_eq!(fits.ids().len(), 56);
        let layout = bank_layout(&fits, CAN1_BANKS).unwrap();
        assert!(layout.exact);
        assert_eq!(layout.banks.len(), 14);

        let beyond = AcceptanceList::of(node(5), &config::<64>(64));
        assert_eq!(beyond.ids().len(), 132);
        let layout = bank_layout(&beyond, CAN1_BANKS).unwrap();
        assert!(!layout.exact);
        assert_eq!(layout.banks.len(), 2);
        for id in 0..=0x7FF {
            let in_range = (0x100..=0x180).contains(&id);
            let expected = in_range || [0x000, 0x001, 0x605, 0x7E5].contains(&id);
            assert_eq!(layout.accepts(id, false), expected, "{id:#x}");
        }
        // The software filter narrows the range to the configured identifiers.
        let partial = AcceptanceList::of(node(5), &config::<64>(27));
        assert_eq!(partial.ids().len(), 58);
        let layout = bank_layout(&partial, CAN1_BANKS).unwrap();
        assert!(!layout.exact && layout.accepts(0x171, false));
        assert!(!partial.accepts(&data(0x171)));
        assert!(!layout.accepts(0x080, false) && !layout.accepts(0x181, false));
    }

    /// Not even the fallback fits one bank: a named error, not a wrong filter.
    #[test]
    fn too_few_banks_is_a_named_error() {
        let beyond = AcceptanceList::of(node(5), &config::<64>(64));
        assert_eq!(
            bank_layout(&beyond, 1),
            Err(FilterError::TooFewBanks { banks: 1 })
        );
        let small = AcceptanceList::of(node(5), &config::<4>(0));
        // No SRDO: one bank, NMT, GFC, SDO and LSS.
        assert_eq!(bank_layout(&small, 1).unwrap().banks.len(), 1);
        assert_eq!(
            bank_layout(&small, 0),
            Err(FilterError::TooFewBanks { banks: 0 })
        );
    }
}
