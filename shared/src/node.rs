//! (being written)
/// Placeholder.
pub struct Node;
/// Placeholder.
pub struct NodeConfig;
/// Placeholder.
pub enum Event {}
/// Placeholder.
pub trait Sink {}
