//! No panicking code path in the firmware: not from the 10 kHz step, and not at all.
//!
//! Reads the release images (the board build and the `qemu` build of nemm-firmware, and both
//! builds of the STM32F407 image) and follows the direct call graph of the Thumb-2 code
//! (`bl`, `b`, conditional branches into other functions) from the handler of the 10 kHz
//! task (SysTick in nemm-firmware, TIM2 on the STM32F407). No function on it may reach a
//! panic symbol (`core::panicking::*`, the panic handler `rust_begin_unwind`, anything named
//! `panic`), and none may call through a register (which the graph could not follow), except
//! into the one trait object of the step: the level tables an estimator or an observer steps
//! on (`dyn LevelStep` in nemm-core). A register call on the path is followed into every
//! implementation of that trait in the image, so the check covers them too.
//!
//! Then the whole image: it may hold no panic symbol at all, so that boot, decoding the
//! weights blob and building the tables cannot panic either (nemm-core's "never panics on
//! any input or blob", checked on the machine code). A failure lists each panic symbol with
//! its callers and a call chain from the reset handler: the place to remove the panic path
//! (an assertion in a `core` function the compiler cannot prove, such as `f32::clamp`'s
//! order check, `chunks_exact`'s non-zero size or `rotate_right`'s length).
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_tests::elf::{is_panic_symbol, CallGraph, Elf};
use nemm_tests::firmware::{BoardImages, Images};
use std::collections::BTreeSet;
use std::path::Path;

/// The trait whose implementations a register call on the step path may reach (the level
/// tables behind `nemm_core::Estimator::attach_levels` and an observer on level tables).
const STEP_TRAIT_OBJECT: &str = " as nemm_core::estimator::levels::LevelStep<";

/// Adds every implementation of [`STEP_TRAIT_OBJECT`]'s methods in the image as a callee of
/// each function that calls through a register, and returns whether the image has any.
fn follow_step_trait_object(g: &mut CallGraph) -> bool {
    let targets: BTreeSet<u32> = g
        .names
        .iter()
        .filter(|(_, n)| n.contains(STEP_TRAIT_OBJECT))
        .map(|(&a, _)| a)
        .collect();
    for f in g.indirect.clone() {
        g.callees
            .entry(f)
            .or_default()
            .extend(targets.iter().copied());
    }
    !targets.is_empty()
}

fn panic_roots(elf: &Elf) -> BTreeSet<u32> {
    elf.symbols
        .iter()
        .filter(|s| s.is_function() && is_panic_symbol(&s.name))
        .map(|s| s.start())
        .collect()
}

/// The panic symbols of the image, each with its callers and a chain from `Reset`.
fn remaining(elf: &Elf, g: &CallGraph, roots: &BTreeSet<u32>) -> Vec<String> {
    let reset = elf.function("Reset").map(|s| s.start());
    let from_reset = reset.map(|r| g.reachable(r)).unwrap_or_default();
    roots
        .iter()
        .map(|&p| {
            let callers: Vec<&str> = g
                .callees
                .iter()
                .filter(|(f, c)| c.contains(&p) && !roots.contains(f))
                .map(|(&f, _)| g.name(f))
                .collect();
            let chain = if from_reset.contains_key(&p) {
                g.chain(&from_reset, p).join(" -> ")
            } else {
                "not reachable from Reset".into()
            };
            format!(
                "{}\n      called by: {}\n      e.g. {chain}",
                g.name(p),
                if callers.is_empty() {
                    "(only other panic functions)".into()
                } else {
                    callers.join(", ")
                }
            )
        })
        .collect()
}

/// Checks the image at `path`, whose 10 kHz step is the interrupt handler `step_handler`.
fn check(path: &Path, what: &str, step_handler: &str) {
    let elf = Elf::read(path).expect("firmware image");
    let mut g = elf.call_graph();
    let followed = follow_step_trait_object(&mut g);
    let step = elf
        .function(step_handler)
        .unwrap_or_else(|| panic!("{what}: no {step_handler} handler in {}", path.display()))
        .start();
    let reached = g.reachable(step);
    let roots = panic_roots(&elf);
    let bad: Vec<String> = reached
        .keys()
        .filter(|f| roots.contains(f))
        .map(|&p| g.chain(&reached, p).join(" -> "))
        .collect();
    assert!(
        bad.is_empty(),
        "{what}: the 10 kHz step can panic:\n  {}",
        bad.join("\n  ")
    );
    let indirect: Vec<&str> = reached
        .keys()
        .filter(|f| g.indirect.contains(f) && !followed)
        .map(|&f| g.name(f))
        .collect();
    assert!(
        indirect.is_empty(),
        "{what}: functions on the step path call through a register (not followed): {indirect:?}"
    );
    let rest = remaining(&elf, &g, &roots);
    assert!(
        rest.is_empty(),
        "{what}: {} panic symbol(s) in the image (boot-time code can panic):\n    {}",
        rest.len(),
        rest.join("\n    ")
    );
    eprintln!(
        "qemu_no_panic: {what}: {} functions reachable from {step_handler}, none panics; no \
         panic symbol in the image",
        reached.len(),
    );
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn no_panic_path_in_the_board_build() {
    let images = Images::from_env();
    check(&images.app_release, "board build", "SysTick");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn no_panic_path_in_the_qemu_build() {
    let images = Images::from_env();
    check(&images.app, "qemu build", "SysTick");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn no_panic_path_in_the_stm32f407_image() {
    let images = BoardImages::from_env();
    check(&images.board, "stm32f407 image", "TIM2");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn no_panic_path_in_the_stm32f407_qemu_image() {
    let images = BoardImages::from_env();
    check(&images.qemu_image, "stm32f407 qemu image", "TIM2");
}
