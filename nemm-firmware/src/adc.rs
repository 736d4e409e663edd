//! The bus protocol the firmware's two 24-bit SPI converters share (the stroke sensor's,
//! [`crate::sensor`], and the load cell's, [`crate::loadcell`]): one SPI transaction writes
//! the converter's read command and reads the result MSB first and a status byte,
//!
//! ```text
//! MOSI: COMMAND
//! MISO:          D[23:16] D[15:8] D[7:0] STATUS
//! ```
//!
//! with the same two status bits. How `D` codes the quantity (offset binary for the
//! displacement, two's complement for the force) is each channel's.

use embedded_hal::spi::{Operation, SpiDevice};

/// Status bit: no new conversion since the last read (active high).
pub const STATUS_NOT_READY: u8 = 1 << 7;
/// Status bit: the conversion is invalid (over/under-range, sensor, bridge or reference
/// fault).
pub const STATUS_ADC_ERROR: u8 = 1 << 6;

/// The 24 data bits and the status byte of one conversion, as they arrive on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawFrame {
    /// `D[23:0]` (bits 24-31 zero).
    pub bits: u32,
    /// Status byte.
    pub status: u8,
}

impl RawFrame {
    /// Bytes as the converter sends them after the command byte (`bits` above 24 dropped).
    pub fn encode(self) -> [u8; 4] {
        let b = self.bits;
        [(b >> 16) as u8, (b >> 8) as u8, b as u8, self.status]
    }

    /// Parses the four bytes after the command byte.
    pub fn decode(bytes: [u8; 4]) -> Self {
        let [d2, d1, d0, status] = bytes;
        Self {
            bits: (u32::from(d2) << 16) | (u32::from(d1) << 8) | u32::from(d0),
            status,
        }
    }
}

/// Reads one conversion with `command` (one SPI transaction).
pub fn read_frame<SPI: SpiDevice>(spi: &mut SPI, command: u8) -> Result<RawFrame, SPI::Error> {
    let mut rx = [0u8; 4];
    spi.transaction(&mut [Operation::Write(&[command]), Operation::Read(&mut rx)])?;
    Ok(RawFrame::decode(rx))
}

/// A converter on a script, for the channels' tests.
#[cfg(test)]
pub(crate) mod script {
    use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
    use std::vec::Vec;

    /// Serves a scripted list of responses and checks the command byte.
    pub(crate) struct Script {
        /// The command every transaction must write.
        pub command: u8,
        /// The responses in order (an `Err` fails that transaction).
        pub frames: Vec<Result<[u8; 4], ErrorKind>>,
        /// The next response.
        pub next: usize,
    }

    impl ErrorType for Script {
        type Error = ErrorKind;
    }

    impl SpiDevice for Script {
        fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
            let resp = self.frames[self.next];
            self.next += 1;
            let [Operation::Write(cmd), Operation::Read(rx)] = ops else {
                panic!("unexpected transaction shape");
            };
            assert_eq!(*cmd, &[self.command]);
            rx.copy_from_slice(&resp?);
            Ok(())
        }
    }
}
