//! Placeholder with the agreed API; replaced by the real storage on merge.
#![allow(missing_docs, unused_variables, clippy::new_without_default)]
pub enum Slot {
    A,
    B,
}
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StorageError {
    Medium,
}
pub trait Flash {
    fn slot_len(&self) -> usize;
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError>;
    fn erase(&mut self, slot: Slot) -> Result<(), StorageError>;
    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError>;
}
pub fn store<F: Flash>(flash: &mut F, payload: &[u8]) -> Result<(), StorageError> {
    Ok(())
}
pub fn load<F: Flash>(flash: &mut F, buf: &mut [u8]) -> Result<Option<usize>, StorageError> {
    Ok(None)
}
pub fn restore_defaults<F: Flash>(flash: &mut F) -> Result<(), StorageError> {
    Ok(())
}
pub struct RamFlash<const N: usize>;
impl<const N: usize> RamFlash<N> {
    pub fn new() -> Self {
        RamFlash
    }
}
impl<const N: usize> Flash for RamFlash<N> {
    fn slot_len(&self) -> usize {
        N
    }
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        Ok(())
    }
    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        Ok(())
    }
    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        Ok(())
    }
}
