//! The board's outputs: the force on DAC channel 1, the status LEDs and the step-time pin.
//!
//! | output | pin | meaning |
//! |--------|-----|---------|
//! | force | PA4 (DAC_OUT1, buffered) | [`FORCE_FULL_SCALE_N`] .. +[`FORCE_FULL_SCALE_N`] over 0 .. VREF+ (12 bits; 0 N at mid-scale, 2048) |
//! | heartbeat | PD12 (green LED on the STM32F4DISCOVERY) | toggles every [`HEARTBEAT_STEPS`] steps: 1 Hz blinking while the 10 kHz loop runs |
//! | fault | PD14 (red LED) | on for good after a clock, weights or estimator error at boot, a period overrun, a sensor error or an invalid sample |
//! | step | PD15 (blue LED) | high while the 10 kHz step runs: its duty cycle on a scope is the step time over 100 us |
//!
//! A non-finite force (never expected: the estimator holds its last good input) drives the
//! DAC to mid-scale.

use stm32f4::stm32f407::{DAC, GPIOA, GPIOD, RCC};

/// The force at the DAC's full scale \[N\]: the output spans -5 kN (0 V) to +5 kN (VREF+).
pub const FORCE_FULL_SCALE_N: f32 = 5_000.0;
/// Steps between heartbeat toggles (0.5 s at 10 kHz).
pub const HEARTBEAT_STEPS: u32 = 5_000;

/// The DAC code of `force_n`: 12 bits, 0 N at 2048, saturating at both ends; mid-scale for
/// a non-finite force.
pub fn dac_code(force_n: f32) -> u16 {
    if !force_n.is_finite() {
        return 2048;
    }
    let x = (force_n / FORCE_FULL_SCALE_N).clamp(-1.0, 1.0);
    // `as` saturates; the product lies in [0, 4095] by the bounds on `x`.
    (2047.5 + 2047.5 * x + 0.5) as u16
}

/// DAC channel 1 on PA4.
pub struct ForceDac {
    dac: DAC,
}

impl ForceDac {
    /// Clocks the DAC and GPIOA, puts PA4 in analog mode, enables channel 1 (output buffer
    /// on, no trigger: a write to the holding register converts at once) at mid-scale.
    pub fn new(dac: DAC, rcc: &RCC, gpioa: &GPIOA) -> Self {
        rcc.ahb1enr().modify(|_, w| w.gpioaen().set_bit());
        rcc.apb1enr().modify(|_, w| w.dacen().set_bit());
        gpioa.moder().modify(|_, w| w.moder4().analog());
        dac.dhr12r1().write(|w| w.daccdhr().set(2048));
        dac.cr().modify(|_, w| w.en1().enabled());
        Self { dac }
    }

    /// Outputs `force_n` ([`dac_code`]).
    #[inline(always)]
    pub fn publish(&mut self, force_n: f32) {
        let code = dac_code(force_n);
        self.dac.dhr12r1().write(|w| w.daccdhr().set(code));
    }
}

/// The three pins on GPIOD.
#[derive(Clone, Copy)]
pub struct Leds(());

impl Leds {
    /// Clocks GPIOD and makes PD12, PD14 and PD15 outputs, all low.
    pub fn new(rcc: &RCC, gpiod: &GPIOD) -> Self {
        rcc.ahb1enr().modify(|_, w| w.gpioden().set_bit());
        gpiod.bsrr().write(|w| {
            w.br12().set_bit();
            w.br14().set_bit();
            w.br15().set_bit()
        });
        gpiod.moder().modify(|_, w| {
            w.moder12().output();
            w.moder14().output();
            w.moder15().output()
        });
        Self(())
    }

    fn gpiod() -> &'static stm32f4::stm32f407::gpioi::RegisterBlock {
        // SAFETY: BSRR writes are atomic per pin, ODR is only read; the three pins belong to
        // this type (made once in `init`).
        unsafe { &*GPIOD::ptr() }
    }

    /// Toggles the heartbeat LED (PD12).
    #[inline(always)]
    pub fn toggle_heartbeat(self) {
        let d = Self::gpiod();
        if d.odr().read().odr12().bit_is_set() {
            d.bsrr().write(|w| w.br12().set_bit());
        } else {
            d.bsrr().write(|w| w.bs12().set_bit());
        }
    }

    /// Turns the fault LED (PD14) on.
    #[inline(always)]
    pub fn fault(self) {
        Self::gpiod().bsrr().write(|w| w.bs14().set_bit());
    }

    /// Drives the step pin (PD15): high while the step runs.
    #[inline(always)]
    pub fn step(self, busy: bool) {
        let d = Self::gpiod();
        if busy {
            d.bsrr().write(|w| w.bs15().set_bit());
        } else {
            d.bsrr().write(|w| w.br15().set_bit());
        }
    }
}
