//! SDO and NMT over a [`Transport`]: the SDO transfers are shared's client
//! (`shared::canopen::sdo_client`, expedited and segmented); this module moves its requests
//! over the bus and turns its errors into sentences naming the node and the object.

use crate::error::{Object, ToolError};
use crate::transport::{Transport, TransportError};
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::Address;
use shared::canopen::sdo_client::{self, ClientError};
use shared::{CanFrame, CanId};
use std::time::Duration;

/// The tool's side of the bus.
pub struct Client<T: Transport> {
    /// The interface.
    pub transport: T,
    /// How long one SDO request may wait for its answer.
    pub sdo_timeout: Duration,
    /// SDO requests sent (for reports and benchmarks).
    pub requests: u64,
}

impl<T: Transport> Client<T> {
    /// A client on `transport` with the SDO timeout `sdo_timeout`.
    pub fn new(transport: T, sdo_timeout: Duration) -> Self {
        Client {
            transport,
            sdo_timeout,
            requests: 0,
        }
    }

    /// One SDO request to `node` and its answer, `None` after the SDO timeout. A transport
    /// failure is kept in `failure`.
    fn exchange(
        &mut self,
        node: u8,
        request: [u8; 8],
        failure: &mut Option<TransportError>,
    ) -> Option<[u8; 8]> {
        let result = (|| {
            let to = CanId::new(0x600 + u16::from(node)).map_err(|_| {
                TransportError::Protocol(format!("node-ID {node} has no SDO identifier"))
            })?;
            let from = 0x580 + u16::from(node);
            let frame = CanFrame::new(to, &request)
                .map_err(|_| TransportError::Protocol("SDO request longer than 8".into()))?;
            // Frames that arrived before this request cannot answer it (another SDO client's
            // transfer with the same node, say, while this one was idle): they are dropped,
            // not taken for the answer.
            let now = self.transport.now();
            while self.transport.receive(now)?.is_some() {}
            self.requests += 1;
            self.transport.send(&frame)?;
            let deadline = self.transport.now() + self.sdo_timeout;
            while let Some(frame) = self.transport.receive(deadline)? {
                if frame.id().raw() == from && !frame.is_remote() {
                    if let Ok(answer) = <[u8; 8]>::try_from(frame.data()) {
                        return Ok(Some(answer));
                    }
                }
            }
            Ok(None)
        })();
        result.unwrap_or_else(|error| {
            *failure = Some(error);
            None
        })
    }

    fn error(
        &self,
        node: u8,
        address: Address,
        action: &'static str,
        error: ClientError,
    ) -> ToolError {
        let object = Object(address);
        match error {
            ClientError::Aborted(abort) => ToolError::Aborted {
                node,
                object,
                action,
                code: abort.code(),
            },
            ClientError::UnknownAbort(code) => ToolError::Aborted {
                node,
                object,
                action,
                code,
            },
            ClientError::NoResponse => ToolError::Timeout {
                node,
                object,
                action,
                timeout_ms: self.sdo_timeout.as_millis() as u64,
            },
            ClientError::Protocol => ToolError::Protocol {
                node,
                object,
                action,
            },
            ClientError::TooLong => ToolError::TooLong {
                node,
                object,
                max: shared::canopen::sdo::MAX_OBJECT_LEN,
            },
        }
    }

    /// Writes `data` to `address` of `node` (SDO download).
    pub fn write(&mut self, node: u8, address: Address, data: &[u8]) -> Result<(), ToolError> {
        let mut failure = None;
        let result = sdo_client::download(
            |request| self.exchange(node, request, &mut failure),
            address,
            data,
        );
        if let Some(error) = failure {
            return Err(error.into());
        }
        result.map_err(|error| self.error(node, address, "write", error))
    }

    /// Reads `address` of `node` (SDO upload).
    pub fn read(&mut self, node: u8, address: Address) -> Result<Vec<u8>, ToolError> {
        let mut failure = None;
        let result = sdo_client::upload(
            |request| self.exchange(node, request, &mut failure),
            address,
        );
        if let Some(error) = failure {
            return Err(error.into());
        }
        result
            .map(|value| value.to_vec())
            .map_err(|error| self.error(node, address, "read", error))
    }

    /// Reads an unsigned value of `len` bytes (1, 2 or 4) and checks its length.
    pub fn read_unsigned(
        &mut self,
        node: u8,
        address: Address,
        len: usize,
    ) -> Result<u32, ToolError> {
        let bytes = self.read(node, address)?;
        if bytes.len() != len {
            return Err(ToolError::Length {
                node,
                object: Object(address),
                expected: len,
                got: bytes.len(),
            });
        }
        let mut raw = [0u8; 4];
        raw[..len].copy_from_slice(&bytes);
        Ok(u32::from_le_bytes(raw))
    }

    /// Sends an NMT command to `target` (0: every node).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) -> Result<(), ToolError> {
        self.transport.send(&nmt::command_frame(command, target))?;
        Ok(())
    }

    /// Every frame received during `duration`.
    pub fn listen(&mut self, duration: Duration) -> Result<Vec<(Duration, CanFrame)>, ToolError> {
        let deadline = self.transport.now() + duration;
        let mut frames = Vec::new();
        while let Some(frame) = self.transport.receive(deadline)? {
            frames.push((self.transport.now(), frame));
        }
        Ok(frames)
    }
}
