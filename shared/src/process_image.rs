//! The application objects of a device (the SR application objects that SRDO mappings point
//! at, EN 50325-5 6.1) and the bytes that hold their values.
//!
//! A device describes its application objects once, as a `'static` table of [`AppObject`]s.
//! [`ProcessImage::new`] checks the table and lays the values out in one small byte array;
//! SRDO mappings are resolved against it when a configuration is validated, so the runtime
//! copies bytes between frames and the image without looking anything up.
//!
//! The safe state of every value is 0 (SC_REQ_05): [`ProcessImage::new`] starts all-zero, and
//! the node clears every received value whenever it is not in its working state.

use crate::canopen::od::{AbortCode, Address};

/// Total bytes of application data a device can hold.
pub const PROCESS_IMAGE_LEN: usize = 64;
/// The most application objects a device can describe.
pub const MAX_APP_OBJECTS: usize = 64;

/// How an application object may be accessed by SDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Readable; written only by the application or by a received SRDO.
    ReadOnly,
    /// Readable and writable by SDO (only outside Operational: these are safety values).
    ReadWrite,
}

/// In which SRDO direction an application object may be mapped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mappable {
    /// Not mappable into any SRDO.
    No,
    /// Mappable into transmit SRDOs (the device produces this value).
    Transmit,
    /// Mappable into receive SRDOs (the device consumes this value).
    Receive,
}

/// One application object: where it lives in the dictionary, how long it is, and who may
/// touch it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AppObject {
    /// Index and sub-index (sub-index 0 of an array is answered by the image itself).
    pub address: Address,
    /// Length in bytes, `1..=8`.
    pub len: u8,
    /// SDO access.
    pub access: Access,
    /// SRDO mappability.
    pub mappable: Mappable,
}

/// Why an application object table was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TableError {
    /// More than [`MAX_APP_OBJECTS`] objects.
    TooManyObjects,
    /// The values need more than [`PROCESS_IMAGE_LEN`] bytes.
    TooLarge,
    /// An object is 0 or more than 8 bytes long.
    BadLength(Address),
    /// An object's index is outside the application areas 0x2000..=0x9FFF, or its sub-index
    /// is 0 (sub-index 0 is answered by the image).
    BadAddress(Address),
    /// Two objects have the same address.
    Duplicate(Address),
}

/// A contiguous run of bytes in the process image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Span {
    /// First byte.
    pub offset: u8,
    /// Length in bytes.
    pub len: u8,
}

/// The application objects' values, laid out after a checked table.
#[derive(Clone, Debug)]
pub struct ProcessImage {
    table: &'static [AppObject],
    offsets: [u8; MAX_APP_OBJECTS],
    bytes: [u8; PROCESS_IMAGE_LEN],
}

/// The bits that the low `len` bytes occupy in a little-endian `u64` (lengths above 8 count as
/// 8). A table, because the receive hot path needs it several times per SRDO pair.
#[inline]
pub const fn byte_mask(len: u8) -> u64 {
    const MASKS: [u64; 9] = {
        let mut masks = [u64::MAX; 9];
        let mut len = 0;
        while len < 8 {
            masks[len] = (1u64 << (len * 8)) - 1;
            len += 1;
        }
        masks
    };
    let index = if len < 8 { len as usize } else { 8 };
    MASKS[index]
}

impl ProcessImage {
    /// Checks `table` and lays out its values, all zero (the safe state).
    pub fn new(table: &'static [AppObject]) -> Result<Self, TableError> {
        if table.len() > MAX_APP_OBJECTS {
            return Err(TableError::TooManyObjects);
        }
        let mut offsets = [0u8; MAX_APP_OBJECTS];
        let mut next = 0usize;
        for (position, object) in table.iter().enumerate() {
            if object.len == 0 || object.len > 8 {
                return Err(TableError::BadLength(object.address));
            }
            if !(0x2000..=0x9FFF).contains(&object.address.index) || object.address.sub == 0 {
                return Err(TableError::BadAddress(object.address));
            }
            if table[..position]
                .iter()
                .any(|earlier| earlier.address == object.address)
            {
                return Err(TableError::Duplicate(object.address));
            }
            let end = next + usize::from(object.len);
            if end > PROCESS_IMAGE_LEN {
                return Err(TableError::TooLarge);
            }
            // `next < PROCESS_IMAGE_LEN <= 255`, so the offset fits in a byte.
            offsets[position] = next as u8;
            next = end;
        }
        Ok(ProcessImage {
            table,
            offsets,
            bytes: [0; PROCESS_IMAGE_LEN],
        })
    }

    /// The object table.
    pub fn table(&self) -> &'static [AppObject] {
        self.table
    }

    /// The object at `address` and the span of its value.
    pub fn find(&self, address: Address) -> Option<(AppObject, Span)> {
        let position = self
            .table
            .iter()
            .position(|object| object.address == address)?;
        let object = self.table[position];
        Some((
            object,
            Span {
                offset: self.offsets[position],
                len: object.len,
            },
        ))
    }

    /// `true` when some application object has index `index`.
    pub fn has_index(&self, index: u16) -> bool {
        self.table
            .iter()
            .any(|object| object.address.index == index)
    }

    /// The highest sub-index defined for `index` (the value of its sub-index 0).
    pub fn highest_sub(&self, index: u16) -> Option<u8> {
        self.table
            .iter()
            .filter(|object| object.address.index == index)
            .map(|o| o.address.sub)
            .max()
    }

    /// The bytes of `span`.
    #[inline]
    pub fn get(&self, span: Span) -> &[u8] {
        let start = usize::from(span.offset);
        // Spans come from `find`, whose offsets and lengths were checked against the image
        // length in `new`; `get` with a foreign span still cannot panic: it is clamped.
        let end = (start + usize::from(span.len)).min(PROCESS_IMAGE_LEN);
        self.bytes.get(start.min(end)..end).unwrap_or(&[])
    }

    /// The 8 bytes from the start of `span`, zero past the end of the image: a fixed-size
    /// window the transmit hot path copies whole (one load and store) instead of a copy call
    /// of the span's length. Its first bytes are [`ProcessImage::get`]'s. Out of line in the
    /// firmware images (two call sites, each with the copy past the image's end).
    #[cfg_attr(target_os = "none", inline(never))]
    #[cfg_attr(not(target_os = "none"), inline)]
    pub fn window(&self, span: Span) -> [u8; 8] {
        let start = usize::from(span.offset);
        let mut window = [0u8; 8];
        match self.bytes.get(start..start + 8) {
            Some(bytes) => window.copy_from_slice(bytes),
            None => {
                let tail = self.bytes.get(start..).unwrap_or_default();
                let count = tail.len().min(8);
                window[..count].copy_from_slice(&tail[..count]);
            }
        }
        window
    }

    /// The 8 bytes from the start of `span` as a little-endian `u64`: the bytes of
    /// [`ProcessImage::window`], one load where a whole window fits in the image.
    #[inline]
    pub fn word(&self, span: Span) -> u64 {
        let start = usize::from(span.offset);
        match self
            .bytes
            .get(start..start + 8)
            .and_then(|bytes| <[u8; 8]>::try_from(bytes).ok())
        {
            Some(bytes) => u64::from_le_bytes(bytes),
            None => self.tail_word(span),
        }
    }

    /// [`ProcessImage::word`] of a span whose window runs past the image. Cold: kept out of
    /// the transmit hot path, where no valid mapping comes.
    #[cold]
    #[inline(never)]
    fn tail_word(&self, span: Span) -> u64 {
        u64::from_le_bytes(self.window(span))
    }

    /// How many bytes [`ProcessImage::get`] gives for `span`: its length, clamped to the
    /// image.
    #[inline]
    pub fn span_len(span: Span) -> usize {
        let start = usize::from(span.offset);
        let end = (start + usize::from(span.len)).min(PROCESS_IMAGE_LEN);
        end.saturating_sub(start)
    }

    /// Copies `data` into `span` (as much as both hold).
    #[inline]
    pub fn set(&mut self, span: Span, data: &[u8]) {
        let start = usize::from(span.offset);
        let end = (start + usize::from(span.len)).min(PROCESS_IMAGE_LEN);
        if let Some(target) = self.bytes.get_mut(start.min(end)..end) {
            let count = target.len().min(data.len());
            target[..count].copy_from_slice(&data[..count]);
        }
    }

    /// Sets the bytes of `span` (at most 8) to the low bytes of `value`, little-endian.
    ///
    /// The receive hot path: where an 8-byte window fits in the image it is one read-modify-
    /// write of a `u64` instead of a copy call per object; the bytes outside `span` are written
    /// back unchanged.
    #[inline]
    pub fn put_le(&mut self, span: Span, value: u64) {
        let start = usize::from(span.offset);
        let len = usize::from(span.len).min(8);
        let mask = byte_mask(span.len);
        if let Some(window) = self
            .bytes
            .get_mut(start..start + 8)
            .and_then(|window| <&mut [u8; 8]>::try_from(window).ok())
        {
            let old = u64::from_le_bytes(*window);
            *window = ((old & !mask) | (value & mask)).to_le_bytes();
        } else {
            self.set(span, &value.to_le_bytes()[..len]);
        }
    }

    /// Sets the bytes of `span` to 0, the safe state (SC_REQ_05).
    #[inline]
    pub fn clear(&mut self, span: Span) {
        let start = usize::from(span.offset);
        let end = (start + usize::from(span.len)).min(PROCESS_IMAGE_LEN);
        if let Some(target) = self.bytes.get_mut(start.min(end)..end) {
            target.fill(0);
        }
    }

    /// Sets every value to 0, the safe state (SC_REQ_05).
    pub fn clear_all(&mut self) {
        self.bytes.fill(0);
    }

    /// Reads `address` by SDO rules into `buf`; sub-index 0 of an application index answers
    /// the highest sub-index.
    pub fn read(&self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        if address.sub == 0 {
            let highest = self.highest_sub(address.index).ok_or(AbortCode::NoObject)?;
            let slot = buf.first_mut().ok_or(AbortCode::OutOfMemory)?;
            *slot = highest;
            return Ok(1);
        }
        let (_, span) = self.find(address).ok_or(if self.has_index(address.index) {
            AbortCode::NoSubIndex
        } else {
            AbortCode::NoObject
        })?;
        let value = self.get(span);
        let target = buf.get_mut(..value.len()).ok_or(AbortCode::OutOfMemory)?;
        target.copy_from_slice(value);
        Ok(value.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const fn object(index: u16, sub: u8, len: u8) -> AppObject {
        AppObject {
            address: Address::new(index, sub),
            len,
            access: Access::ReadOnly,
            mappable: Mappable::Transmit,
        }
    }

    static TABLE: [AppObject; 3] = [
        object(0x6000, 1, 1),
        object(0x6000, 2, 2),
        object(0x6001, 1, 1),
    ];

    #[test]
    fn objects_are_laid_out_in_table_order_and_start_in_the_safe_state() {
        let image = ProcessImage::new(&TABLE).unwrap();
        let (_, span) = image.find(Address::new(0x6001, 1)).unwrap();
        assert_eq!(span, Span { offset: 3, len: 1 });
        assert!(
            image.bytes.iter().all(|&b| b == 0),
            "SC_REQ_05: safe state is 0"
        );
    }

    /// The word-wide receive path writes exactly what the byte copy writes, at every offset
    /// (the end of the image included) and every length, and nothing else.
    #[test]
    fn put_le_equals_a_byte_copy_everywhere() {
        let value = 0x8877_6655_4433_2211u64;
        for offset in 0..PROCESS_IMAGE_LEN as u8 {
            for len in 0..=8u8 {
                let span = Span { offset, len };
                let mut by_word = ProcessImage::new(&TABLE).unwrap();
                let mut by_byte = ProcessImage::new(&TABLE).unwrap();
                by_word.bytes.fill(0xEE);
                by_byte.bytes.fill(0xEE);
                by_word.put_le(span, value);
                by_byte.set(span, &value.to_le_bytes()[..usize::from(len)]);
                assert_eq!(by_word.bytes, by_byte.bytes, "offset {offset} len {len}");
            }
        }
    }

    /// The transmit path's window starts with exactly the bytes `get` gives and is zero past
    /// the image's end, at every offset (past the end included) and every length.
    #[test]
    fn a_window_starts_with_the_bytes_of_its_span() {
        let mut image = ProcessImage::new(&TABLE).unwrap();
        for (at, byte) in image.bytes.iter_mut().enumerate() {
            *byte = (at as u8).wrapping_mul(37) | 1;
        }
        for offset in 0..=u8::MAX {
            for len in 0..=12u8 {
                let span = Span { offset, len };
                let window = image.window(span);
                let bytes = image.get(span);
                let count = bytes.len().min(8);
                assert_eq!(
                    &window[..count],
                    &bytes[..count],
                    "offset {offset} len {len}"
                );
                let inside = PROCESS_IMAGE_LEN.saturating_sub(usize::from(offset)).min(8);
                assert!(
                    window[inside..].iter().all(|&byte| byte == 0),
                    "offset {offset}: zero past the image"
                );
            }
        }
    }

    /// The word is the window read little-endian, and the clamped length is `get`'s, at every
    /// offset (past the end included) and every length.
    #[test]
    fn a_word_is_its_window_and_a_span_len_is_what_get_gives() {
        let mut image = ProcessImage::new(&TABLE).unwrap();
        for (at, byte) in image.bytes.iter_mut().enumerate() {
            *byte = (at as u8).wrapping_mul(37) | 1;
        }
        for offset in 0..=u8::MAX {
            for len in 0..=12u8 {
                let span = Span { offset, len };
                assert_eq!(image.word(span), u64::from_le_bytes(image.window(span)));
                assert_eq!(ProcessImage::span_len(span), image.get(span).len());
            }
        }
    }

    #[test]
    fn bad_tables_are_refused_with_the_reason() {
        static ZERO: [AppObject; 1] = [object(0x6000, 1, 0)];
        static DUPLICATE: [AppObject; 2] = [object(0x6000, 1, 1), object(0x6000, 1, 1)];
        static COMMUNICATION_AREA: [AppObject; 1] = [object(0x1000, 1, 1)];
        static BIG: [AppObject; 9] = [
            object(0x6000, 1, 8),
            object(0x6000, 2, 8),
            object(0x6000, 3, 8),
            object(0x6000, 4, 8),
            object(0x6000, 5, 8),
            object(0x6000, 6, 8),
            object(0x6000, 7, 8),
            object(0x6000, 8, 8),
            object(0x6000, 9, 1),
        ];
        assert_eq!(
            ProcessImage::new(&ZERO).err(),
            Some(TableError::BadLength(Address::new(0x6000, 1)))
        );
        assert_eq!(
            ProcessImage::new(&DUPLICATE).err(),
            Some(TableError::Duplicate(Address::new(0x6000, 1)))
        );
        assert_eq!(
            ProcessImage::new(&COMMUNICATION_AREA).err(),
            Some(TableError::BadAddress(Address::new(0x1000, 1)))
        );
        assert_eq!(ProcessImage::new(&BIG).err(), Some(TableError::TooLarge));
    }

    #[test]
    fn sdo_reads_answer_values_highest_sub_index_and_specific_aborts() {
        let mut image = ProcessImage::new(&TABLE).unwrap();
        let (_, span) = image.find(Address::new(0x6000, 2)).unwrap();
        image.set(span, &[0x34, 0x12]);
        let mut buf = [0u8; 8];
        assert_eq!(image.read(Address::new(0x6000, 2), &mut buf), Ok(2));
        assert_eq!(&buf[..2], &[0x34, 0x12]);
        assert_eq!(image.read(Address::new(0x6000, 0), &mut buf), Ok(1));
        assert_eq!(buf[0], 2);
        assert_eq!(
            image.read(Address::new(0x6000, 3), &mut buf),
            Err(AbortCode::NoSubIndex)
        );
        assert_eq!(
            image.read(Address::new(0x6002, 1), &mut buf),
            Err(AbortCode::NoObject)
        );
        assert_eq!(
            image.read(Address::new(0x6000, 2), &mut buf[..1]),
            Err(AbortCode::OutOfMemory)
        );
    }

    #[test]
    fn foreign_spans_are_clamped_not_panicking() {
        let mut image = ProcessImage::new(&TABLE).unwrap();
        let outside = Span {
            offset: 250,
            len: 8,
        };
        assert!(image.get(outside).is_empty());
        image.set(outside, &[1; 8]);
        image.clear(outside);
    }
}
