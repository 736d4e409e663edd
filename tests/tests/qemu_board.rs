//! The STM32F407 image (`boards/nemm-stm32f407`, `qemu` feature) boots on QEMU's
//! `netduinoplus2` (an STM32F405: same core, flash, SRAM, SPI and timers; no RCC model, so
//! the image skips its clock waits) and runs its 10 kHz loop: TIM2's update interrupt, the
//! stroke sensor on the chip's SPI2 through nemm-firmware's driver, the table-mode
//! estimator, the DAC write.
//!
//! QEMU's SPI2 has nothing attached and answers every byte with 0: a ready conversion at
//! the bottom of the range, so the sensor path runs without errors at a constant stroke.
//! What this checks is that the image boots, decodes its weights, builds its tables and
//! keeps the 10 kHz loop going without overruns, and that its boot stack fits the board's
//! stack region; cycle figures need the board (QEMU has no cycle counter).
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_tests::elf::Elf;
use nemm_tests::firmware::{run_machine, BoardImages};
use std::time::Duration;

/// Steps of the QEMU run (`QEMU_RUN_STEPS` of the board crate).
const RUN_STEPS: u32 = 20_000;

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn stm32f407_image_runs_its_10_khz_loop_on_netduinoplus2() {
    let images = BoardImages::from_env();
    let run = run_machine(
        &images.qemu,
        &["-machine", "netduinoplus2"],
        &images.qemu_image,
        "enable=on,target=native",
        Duration::from_secs(300),
    );
    assert_eq!(run.code, Some(0), "{}", run.describe());
    let out = run.output();
    let boot = out.expect("boot");
    assert_eq!(boot.get("board"), Some("stm32f407"), "{}", run.describe());
    let clock = out.expect("clock");
    assert_eq!(clock.num("sysclk_hz"), 168_000_000);
    assert_eq!(clock.get("ready_waits"), Some("skipped"));
    let weights = out.expect("weights ok");
    assert_eq!(weights.get("mode"), Some("table"), "{}", run.describe());
    // The embedded blob stores its tables at the board's alpha: none are built at boot.
    assert_eq!(weights.get("tables"), Some("stored"), "{}", run.describe());
    assert_eq!(weights.get("kind"), Some("nemm"));
    assert_eq!(out.expect("start").num("rate_hz"), 10_000);

    // A status line per second of emulated time, then the summary.
    let status: Vec<u32> = out
        .lines
        .iter()
        .filter(|l| l.starts_with("status "))
        .map(|l| {
            nemm_tests::firmware::Output::parse(l)
                .expect("status")
                .num("steps")
        })
        .collect();
    assert!(
        status.len() >= 2 && status.windows(2).all(|w| w[0] < w[1]),
        "status lines {status:?}\n{}",
        run.describe()
    );
    let summary = out.expect("summary");
    assert!(summary.num("steps") >= RUN_STEPS, "{}", run.describe());
    assert_eq!(summary.num("overruns"), 0, "{}", run.describe());
    assert_eq!(summary.num("sensor_errors"), 0, "{}", run.describe());
    assert_eq!(summary.num("invalid_samples"), 0, "{}", run.describe());
    // The boot stack (painted) fits the stack region of the board's own layout
    // (boards/stm32f407.x: SRAM1+2, the statics being in CCM), which the QEMU layout is
    // larger than.
    let board = Elf::read(&images.board).expect("board image");
    let symbol = |name: &str| {
        board
            .symbols
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no symbol {name} in the board image"))
            .value
    };
    let room = symbol("_stack_start") - symbol("_stack_end");
    let stack = summary.num("stack_used");
    assert!(
        stack < room,
        "the boot stack ({stack} B) does not fit the board's {room} B"
    );
    let force = f32::from_bits(summary.num("force"));
    assert!(force.is_finite(), "force {force}\n{}", run.describe());
    eprintln!(
        "qemu_board: {} steps at 10 kHz on netduinoplus2 in {:.1} s, 0 overruns, force {force} \
         N, stack peak {stack} B of the board's {room} B",
        summary.num("steps"),
        run.wall.as_secs_f64()
    );
}
