//! The CANopen node-ID, `1..=127` (EN 50325-4).

/// A CANopen node-ID, `1..=127`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NodeId(u8);

/// The value is not a valid node-ID (0 or above 127).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InvalidNodeId(pub u8);

impl NodeId {
    /// The node-ID `raw`, if it is in `1..=127`.
    pub const fn new(raw: u8) -> Result<Self, InvalidNodeId> {
        if raw >= 1 && raw <= 127 {
            Ok(NodeId(raw))
        } else {
            Err(InvalidNodeId(raw))
        }
    }

    /// The raw node-ID.
    #[inline]
    pub const fn raw(self) -> u8 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_are_one_to_one_hundred_twenty_seven() {
        assert_eq!(NodeId::new(0), Err(InvalidNodeId(0)));
        assert_eq!(NodeId::new(1).map(NodeId::raw), Ok(1));
        assert_eq!(NodeId::new(127).map(NodeId::raw), Ok(127));
        assert_eq!(NodeId::new(128), Err(InvalidNodeId(128)));
    }
}
