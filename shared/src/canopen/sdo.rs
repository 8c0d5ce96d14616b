//! Placeholder with the agreed API; replaced by the real SDO server on merge.
#![allow(missing_docs, unused_variables)]
use super::od::ObjectDictionary;
use crate::time::{Duration, Instant};
pub const MAX_OBJECT_LEN: usize = 64;
pub struct SdoServer;
impl SdoServer {
    pub const fn new(timeout: Duration) -> Self {
        SdoServer
    }
    pub fn handle(
        &mut self,
        now: Instant,
        request: &[u8],
        dictionary: &mut impl ObjectDictionary,
    ) -> Option<[u8; 8]> {
        None
    }
    pub fn poll(&mut self, now: Instant) -> Option<[u8; 8]> {
        None
    }
    pub fn deadline(&self) -> Option<Instant> {
        None
    }
    pub fn reset(&mut self) {}
}
