//! CANopen Safety and SimpleCAN at once: the SRDO table and the SimpleCAN layer in one
//! protocol slot ([`SrdoAndSimpleCan`]), each frame and object dispatched to its owner.
//!
//! The two share nothing but the shell: their identifiers are disjoint (SimpleCAN 02Fh..07Fh,
//! the SRDOs 101h..180h, `docs/simplecan.md` section 1), so are their objects (1301h..13FFh
//! and 5C00h; 5E00h..5EFFh). With SimpleCAN disabled (5E00h:04 = 0) the SimpleCAN layer
//! checks nothing, sends nothing and claims only frames on 02Fh..07Fh, which the shell ignores
//! anyway: the device is the CANopen Safety node it is without it.

use super::simplecan::{SimpleCan, SimpleCanObjects};
use super::slot::{Refused, RowImage, SafetyProtocol, Slot};
use super::srdo_table::{IMAGE_PER_SRDO, SrdoTable};
use super::{NodeConfig, PersistError, SafeStateCause, Sink};
use crate::canopen::od::{AbortCode, Address};
use crate::frame::CanFrame;
use crate::process_image::ProcessImage;
use crate::time::Instant;

/// The SRDO table of `N` SRDOs (`0..=32`) beside a SimpleCAN layer of `E` SDD entries; `R`
/// sizes the stored image and the signatures (`BothImage`, [`BothSignatures`]).
///
/// `R` is `N` unless given, which holds both for `N ≥ 2`. A device that speaks SimpleCAN
/// instead of SRDOs has a table of none (`N` = 0: 13FEh and 13FFh:00 = 0 only) and takes
/// `R` = 1: the firmware images with SimpleCAN (`board::Protocol`), whose flash the SRDO
/// table's code would otherwise take (docs/footprint.md). Stable Rust has no `N + 2`, so the
/// row count is a parameter of its own, checked when the pair is built.
pub struct SrdoAndSimpleCan<const N: usize, const E: usize, const R: usize = N> {
    /// CANopen Safety.
    pub srdo: SrdoTable<N>,
    /// SimpleCAN.
    pub simplecan: SimpleCan<E>,
}

/// What a device whose slot holds an SRDO table gives access to (the SRDO-specific methods
/// of [`super::Device`] are written once for every such slot).
pub trait WithSrdoTable {
    /// The table's type (an `SrdoTable<N>`).
    type Table;
    /// The SRDO table.
    fn srdo_table(&self) -> &Self::Table;
    /// The SRDO table, mutably.
    fn srdo_table_mut(&mut self) -> &mut Self::Table;
}

impl<const N: usize> WithSrdoTable for SrdoTable<N> {
    type Table = SrdoTable<N>;
    fn srdo_table(&self) -> &SrdoTable<N> {
        self
    }
    fn srdo_table_mut(&mut self) -> &mut SrdoTable<N> {
        self
    }
}

impl<const N: usize, const E: usize, const R: usize> WithSrdoTable for SrdoAndSimpleCan<N, E, R> {
    type Table = SrdoTable<N>;
    fn srdo_table(&self) -> &SrdoTable<N> {
        &self.srdo
    }
    fn srdo_table_mut(&mut self) -> &mut SrdoTable<N> {
        &mut self.srdo
    }
}

/// The signatures of both: the SRDO table's `N` (0x13FF), then SimpleCAN's CRC-32 (5EFFh) as
/// two halves, the rest 0. `2 × R` in all, which holds the `N + 2` (an array of arrays, as
/// the stored images are: stable Rust has no `N + 2`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BothSignatures<const R: usize>([[u16; R]; 2]);

impl<const R: usize> AsRef<[u16]> for BothSignatures<R> {
    fn as_ref(&self) -> &[u16] {
        self.0.as_flattened()
    }
}

impl<const R: usize> AsMut<[u16]> for BothSignatures<R> {
    fn as_mut(&mut self) -> &mut [u16] {
        self.0.as_flattened_mut()
    }
}

/// The stored image of both: `R` rows of twice an SRDO's, which holds the SRDO table's section
/// and SimpleCAN's for the counts the build check (`persist`) accepts (4 SRDOs: up to 51
/// entries; no SRDOs and `R` = 1: up to 14).
pub type BothImage<const R: usize> = RowImage<{ 2 * IMAGE_PER_SRDO }, R>;

impl<const N: usize, const E: usize, const R: usize> SrdoAndSimpleCan<N, E, R> {
    /// The SRDO table of the device described by `config` (`None` when `N` is more than 32)
    /// and a SimpleCAN layer, disabled until configured. A pair whose `R` cannot hold the
    /// `N + 2` signatures does not build.
    pub fn new(config: &NodeConfig) -> Option<Self> {
        const {
            assert!(
                N + 2 <= 2 * R,
                "R rows of signatures hold 2 R: the SRDOs' N and SimpleCAN's 2"
            )
        };
        if N > 32 {
            return None;
        }
        Some(SrdoAndSimpleCan {
            srdo: SrdoTable::beside(config)?,
            simplecan: SimpleCan::new(),
        })
    }
}

impl<const N: usize, const E: usize, const R: usize> SafetyProtocol for SrdoAndSimpleCan<N, E, R> {
    /// The SRDO table's section, with its length first, then SimpleCAN's.
    const MAX_PERSISTED: usize = 2 + SrdoTable::<N>::MAX_PERSISTED + SimpleCan::<E>::MAX_PERSISTED;

    type Image = BothImage<R>;

    fn image() -> BothImage<R> {
        RowImage::zeroed()
    }

    fn load_defaults(&mut self, config: &NodeConfig) {
        self.srdo.load_defaults(config);
        self.simplecan.load_defaults(config);
    }

    fn persist(&self, out: &mut [u8]) -> usize {
        let Some((length, rest)) = out.split_at_mut_checked(2) else {
            return 0;
        };
        let srdo = self.srdo.persist(rest);
        // At most the table of 32 SRDOs' 2,530 bytes: fits a u16.
        length.copy_from_slice(&(srdo as u16).to_le_bytes());
        let simplecan = rest
            .get_mut(srdo..)
            .map_or(0, |tail| self.simplecan.persist(tail));
        2 + srdo + simplecan
    }

    /// All or nothing: SimpleCAN's section is read first (into its objects, on the stack:
    /// 15 + 16 × E bytes), then the SRDO table is restored, then SimpleCAN's objects are put in
    /// force.
    fn restore(&mut self, bytes: &[u8]) -> Result<(), PersistError> {
        let (length, rest) = bytes.split_at_checked(2).ok_or(PersistError::Malformed)?;
        let length = usize::from(u16::from_le_bytes([length[0], length[1]]));
        let (srdo, simplecan) = rest
            .split_at_checked(length)
            .ok_or(PersistError::Malformed)?;
        let objects = SimpleCanObjects::<E>::from_stored(simplecan)?;
        self.srdo.restore(srdo)?;
        self.simplecan.set_objects(objects);
        Ok(())
    }

    fn withdraw_validation(&mut self) {
        self.srdo.withdraw_validation();
        self.simplecan.withdraw_validation();
    }

    fn owns(&self, index: u16) -> bool {
        self.srdo.owns(index) || self.simplecan.owns(index)
    }

    fn needs_unlock(index: u16) -> bool {
        SrdoTable::<N>::needs_unlock(index) || SimpleCan::<E>::needs_unlock(index)
    }

    type Signatures = BothSignatures<R>;

    const NO_SIGNATURES: BothSignatures<R> = BothSignatures([[0; R]; 2]);

    /// Validated when every protocol in use is: the SRDO table always (its 13FEh gates the
    /// Operational entry), SimpleCAN when enabled. Disabled, its part reads 0.
    fn validated_signatures(&self) -> Option<BothSignatures<R>> {
        let srdo = self.srdo.validated_signatures()?;
        let simplecan = if self.simplecan.objects().enabled == 0 {
            [0; 2]
        } else {
            self.simplecan.validated_signatures()?
        };
        let mut signatures = Self::NO_SIGNATURES;
        // `N + 2 ≤ 2 R` is checked when the pair is built: nothing is left out.
        for (slot, signature) in signatures
            .as_mut()
            .iter_mut()
            .zip(srdo.into_iter().chain(simplecan))
        {
            *slot = signature;
        }
        Some(signatures)
    }

    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        if self.simplecan.owns(address.index) {
            self.simplecan.read(address, buf)
        } else {
            self.srdo.read(address, buf)
        }
    }

    fn write(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode> {
        if self.simplecan.owns(address.index) {
            self.simplecan.write(address, data, image, operational)
        } else {
            self.srdo.write(address, data, image, operational)
        }
    }

    /// Both must accept their configuration: a refusal of SimpleCAN's stops the SRDO table
    /// again (it keeps its own validation: nothing was wrong with it).
    fn start<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Result<(), Refused> {
        self.srdo.start(now, slot)?;
        self.simplecan.start(now, slot).inspect_err(|_| {
            self.srdo.stop(slot.image_mut());
        })
    }

    fn stop(&mut self, image: &mut ProcessImage) {
        self.srdo.stop(image);
        self.simplecan.stop(image);
    }

    fn reset(&mut self) {
        self.srdo.reset();
        self.simplecan.reset();
    }

    #[inline]
    fn on_frame<S: Sink>(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) -> bool {
        self.srdo.on_frame(now, frame, slot) || self.simplecan.on_frame(now, frame, slot)
    }

    fn poll<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) {
        self.srdo.poll(now, slot);
        self.simplecan.poll(now, slot);
    }

    fn deadline(&self, now: Instant, latched: bool) -> Instant {
        self.srdo
            .deadline(now, latched)
            .min(self.simplecan.deadline(now, latched))
    }

    fn enter_safe_state(
        &mut self,
        image: &mut ProcessImage,
        cause: SafeStateCause,
        already_latched: bool,
    ) {
        self.srdo.enter_safe_state(image, cause, already_latched);
        self.simplecan
            .enter_safe_state(image, cause, already_latched);
    }

    fn object_changed(&mut self, offset: u8) -> bool {
        self.srdo.object_changed(offset)
    }

    fn on_transmitted<S: Sink>(&mut self, now: Instant, frame: &CanFrame, slot: &mut Slot<'_, S>) {
        self.simplecan.on_transmitted(now, frame, slot);
    }

    fn on_partner_transmitted<S: Sink>(
        &mut self,
        now: Instant,
        heard: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) {
        self.simplecan
            .on_partner_transmitted(now, heard, frame, slot);
    }
}
