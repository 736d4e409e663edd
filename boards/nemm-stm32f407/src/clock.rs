//! The clock tree: 168 MHz from an 8 MHz HSE crystal through the main PLL (RM0090, section 6).
//!
//! | clock | source | frequency |
//! |-------|--------|-----------|
//! | SYSCLK, HCLK (core, DWT cycle counter) | PLL: HSE / M (8) x N (336) / P (2) | 168 MHz |
//! | PCLK1 (APB1: TIM2, SPI2, DAC) | HCLK / 4 | 42 MHz |
//! | TIM2 kernel clock | 2 x PCLK1 (APB1 prescaler above 1) | 84 MHz |
//! | PCLK2 (APB2) | HCLK / 2 | 84 MHz |
//! | PLL48CK (USB, SDIO, RNG; unused) | VCO / Q (7) | 48 MHz |
//!
//! Flash: 5 wait states (168 MHz at 2.7 V to 3.6 V), with the prefetch buffer and the
//! instruction and data caches (the ART accelerator) on.
//!
//! Each step that waits on a ready flag (HSE, PLL, the switch of SYSCLK) gives up after
//! [`READY_POLLS`] reads with a [`ClockError`], so a board without a crystal reports it
//! instead of hanging. Under the `qemu` feature the waits are skipped: QEMU's netduinoplus2
//! has no RCC model (its registers read as zero), and the emulated core runs at whatever
//! the instruction counter says.

use stm32f4::stm32f407::{FLASH, RCC};

/// Frequency of the external crystal \[Hz\] (8 MHz on the STM32F4DISCOVERY and most boards).
pub const HSE_HZ: u32 = 8_000_000;
/// Core clock \[Hz\].
pub const SYSCLK_HZ: u32 = 168_000_000;
/// TIM2's kernel clock \[Hz\]: twice PCLK1 (42 MHz), since the APB1 prescaler is not 1.
pub const TIM2_CLOCK_HZ: u32 = 84_000_000;

/// PLL input divider: HSE / M = 1 MHz at the VCO input (RM0090 recommends 2 MHz for jitter;
/// 1 MHz is within 1 to 2 MHz and gives integer factors for 168 and 48 MHz).
const PLL_M: u8 = (HSE_HZ / 1_000_000) as u8;
/// PLL multiplier: VCO at 336 MHz.
const PLL_N: u16 = 336;
/// PLL divider of the 48 MHz clock: 336 / 7.
const PLL_Q: u8 = 7;

/// Reads of a ready flag before [`configure`] gives up (each read is a few cycles on the
/// 16 MHz HSI that runs until the switch: far longer than the HSE start-up of 2 ms at most).
pub const READY_POLLS: u32 = 1_000_000;

/// A clock that did not come up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockError {
    /// The HSE oscillator never reported ready (no crystal, wrong `HSE_HZ` hardware).
    Hse,
    /// The PLL never locked.
    Pll,
    /// SYSCLK did not switch to the PLL.
    Switch,
}

impl ClockError {
    /// The name in the `clock-error` line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Hse => "hse-not-ready",
            Self::Pll => "pll-not-locked",
            Self::Switch => "sysclk-not-switched",
        }
    }
}

/// Waits until `ready` holds, at most [`READY_POLLS`] reads; skipped under QEMU.
fn wait(ready: impl Fn() -> bool, error: ClockError) -> Result<(), ClockError> {
    if cfg!(feature = "qemu") {
        return Ok(());
    }
    for _ in 0..READY_POLLS {
        if ready() {
            return Ok(());
        }
    }
    Err(error)
}

/// Sets up the clock tree of the table above; on an error the core stays on the 16 MHz HSI.
pub fn configure(rcc: &RCC, flash: &FLASH) -> Result<(), ClockError> {
    rcc.cr().modify(|_, w| w.hseon().set_bit());
    wait(|| rcc.cr().read().hserdy().bit_is_set(), ClockError::Hse)?;

    // SAFETY (the three raw fields): M = 8, N = 336 and Q = 7 are within the ranges of
    // RM0090 (M 2..=63, N 50..=432 with a 100..=432 MHz VCO, Q 2..=15).
    rcc.pllcfgr().write(|w| unsafe {
        w.pllsrc().hse();
        w.pllm().bits(PLL_M);
        w.plln().bits(PLL_N);
        w.pllp().div2();
        w.pllq().bits(PLL_Q)
    });
    rcc.cr().modify(|_, w| w.pllon().set_bit());
    wait(|| rcc.cr().read().pllrdy().bit_is_set(), ClockError::Pll)?;

    // Wait states before the clock goes up.
    flash.acr().write(|w| {
        w.latency().ws5();
        w.prften().set_bit();
        w.icen().set_bit();
        w.dcen().set_bit()
    });
    rcc.cfgr().modify(|_, w| {
        w.hpre().div1();
        w.ppre1().div4();
        w.ppre2().div2()
    });
    rcc.cfgr().modify(|_, w| w.sw().pll());
    wait(|| rcc.cfgr().read().sws().is_pll(), ClockError::Switch)
}
