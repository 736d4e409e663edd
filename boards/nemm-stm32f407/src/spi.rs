//! The stroke sensor's bus: SPI2 as an `embedded-hal` 1.0 [`SpiBus`], chip select on PB12,
//! combined into the [`SpiDevice`](embedded_hal::spi::SpiDevice) that
//! `nemm_firmware::sensor::StrokeSensor` drives by `embedded_hal_bus::spi::ExclusiveDevice`.
//!
//! | signal | pin | setting |
//! |--------|-----|---------|
//! | SCK | PB13 (AF5) | mode 3 (clock idle high, data captured on the second edge), MSB first |
//! | MISO | PB14 (AF5) | |
//! | MOSI | PB15 (AF5) | |
//! | CS | PB12 (push-pull output) | active low, high between transactions |
//!
//! SPI2 runs at PCLK1 / 16 = 2.625 MHz: the 4-byte frame (command, 24-bit code, status) takes
//! about 14 us of the 100 us period. Every wait on a status flag is bounded
//! ([`FLAG_POLLS`]): a bus that stops answering is an error of that period, never a hang.
//! Under QEMU (netduinoplus2) SPI2 is modelled with nothing attached: every byte reads 0.

use core::convert::Infallible;
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{ErrorType as PinErrorType, OutputPin};
use embedded_hal::spi::{Error, ErrorKind, ErrorType, SpiBus};
use stm32f4::stm32f407::{GPIOB, RCC, SPI2};

/// Reads of a status flag before a transfer gives up: at 2.625 MHz a byte takes 3 us, 500
/// core cycles; the bound is 20 times that.
pub const FLAG_POLLS: u32 = 10_000;

/// What went wrong on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpiError {
    /// A status flag (TXE, RXNE, not BSY) did not come within [`FLAG_POLLS`] reads.
    Timeout,
    /// A received byte was overwritten before it was read (OVR).
    Overrun,
    /// Mode fault: NSS pulled low while master (MODF).
    ModeFault,
}

impl Error for SpiError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Timeout => ErrorKind::Other,
            Self::Overrun => ErrorKind::Overrun,
            Self::ModeFault => ErrorKind::ModeFault,
        }
    }
}

/// SPI2 as a blocking, full-duplex, 8-bit bus master.
pub struct Spi2 {
    spi: SPI2,
}

impl Spi2 {
    /// Clocks SPI2 and GPIOB, puts PB13..15 on AF5 and configures the bus (mode 3,
    /// PCLK1 / 16, software NSS).
    pub fn new(spi: SPI2, rcc: &RCC, gpiob: &GPIOB) -> Self {
        rcc.ahb1enr().modify(|_, w| w.gpioben().set_bit());
        rcc.apb1enr().modify(|_, w| w.spi2en().set_bit());
        gpiob.afrh().modify(|_, w| {
            w.afrh13().af5();
            w.afrh14().af5();
            w.afrh15().af5()
        });
        gpiob.ospeedr().modify(|_, w| {
            w.ospeedr13().high_speed();
            w.ospeedr14().high_speed();
            w.ospeedr15().high_speed()
        });
        gpiob.moder().modify(|_, w| {
            w.moder13().alternate();
            w.moder14().alternate();
            w.moder15().alternate()
        });
        spi.cr1().write(|w| {
            w.cpol().idle_high();
            w.cpha().second_edge();
            w.mstr().master();
            w.br().div16();
            w.lsbfirst().msbfirst();
            w.ssm().enabled();
            w.ssi().slave_not_selected();
            w.spe().enabled()
        });
        Self { spi }
    }

    /// Polls the status register until `ready` holds.
    fn wait(
        &self,
        ready: impl Fn(&stm32f4::stm32f407::spi1::sr::R) -> bool,
    ) -> Result<(), SpiError> {
        for _ in 0..FLAG_POLLS {
            let sr = self.spi.sr().read();
            if sr.modf().bit_is_set() {
                return Err(SpiError::ModeFault);
            }
            if sr.ovr().bit_is_set() {
                // Cleared by reading DR, then SR.
                let _ = self.spi.dr().read();
                let _ = self.spi.sr().read();
                return Err(SpiError::Overrun);
            }
            if ready(&sr) {
                return Ok(());
            }
        }
        Err(SpiError::Timeout)
    }

    /// Sends `byte` and returns the byte received meanwhile.
    fn exchange(&mut self, byte: u8) -> Result<u8, SpiError> {
        self.wait(|sr| sr.txe().bit_is_set())?;
        self.spi.dr().write(|w| w.dr().set(u16::from(byte)));
        self.wait(|sr| sr.rxne().bit_is_set())?;
        Ok(self.spi.dr().read().dr().bits() as u8)
    }
}

impl ErrorType for Spi2 {
    type Error = SpiError;
}

impl SpiBus for Spi2 {
    fn read(&mut self, words: &mut [u8]) -> Result<(), SpiError> {
        for w in words {
            *w = self.exchange(0)?;
        }
        Ok(())
    }

    fn write(&mut self, words: &[u8]) -> Result<(), SpiError> {
        for &w in words {
            self.exchange(w)?;
        }
        Ok(())
    }

    fn transfer(&mut self, read: &mut [u8], write: &[u8]) -> Result<(), SpiError> {
        // Clocks max(read, write) bytes: zeros past the end of `write`, received bytes past
        // the end of `read` dropped (the `SpiBus` contract).
        for i in 0..read.len().max(write.len()) {
            let rx = self.exchange(write.get(i).copied().unwrap_or(0))?;
            if let Some(r) = read.get_mut(i) {
                *r = rx;
            }
        }
        Ok(())
    }

    fn transfer_in_place(&mut self, words: &mut [u8]) -> Result<(), SpiError> {
        for w in words {
            *w = self.exchange(*w)?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), SpiError> {
        self.wait(|sr| sr.bsy().bit_is_clear())
    }
}

/// The sensor's chip select, PB12 (push-pull, starts high: deselected).
pub struct ChipSelect(());

impl ChipSelect {
    /// Configures PB12 as an output, driven high.
    pub fn new(rcc: &RCC, gpiob: &GPIOB) -> Self {
        rcc.ahb1enr().modify(|_, w| w.gpioben().set_bit());
        gpiob.bsrr().write(|w| w.bs12().set_bit());
        gpiob.moder().modify(|_, w| w.moder12().output());
        Self(())
    }

    fn gpiob() -> &'static stm32f4::stm32f407::gpiob::RegisterBlock {
        // SAFETY: BSRR writes are atomic per pin and this type owns PB12 (made once in
        // `init`); no other code writes PB12.
        unsafe { &*GPIOB::ptr() }
    }
}

impl PinErrorType for ChipSelect {
    type Error = Infallible;
}

impl OutputPin for ChipSelect {
    fn set_low(&mut self) -> Result<(), Infallible> {
        Self::gpiob().bsrr().write(|w| w.br12().set_bit());
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        Self::gpiob().bsrr().write(|w| w.bs12().set_bit());
        Ok(())
    }
}

/// Busy-wait delays from the core clock, for `Operation::DelayNs` in an SPI transaction
/// (the stroke driver issues none).
pub struct CycleDelay;

impl DelayNs for CycleDelay {
    fn delay_ns(&mut self, ns: u32) {
        // 168 cycles per microsecond; at least one cycle.
        let cycles =
            (u64::from(ns) * u64::from(crate::clock::SYSCLK_HZ / 1_000_000)).div_ceil(1000);
        cortex_m::asm::delay(u32::try_from(cycles).unwrap_or(u32::MAX).max(1));
    }
}
