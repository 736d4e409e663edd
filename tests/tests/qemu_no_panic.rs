//! No panicking code path is reachable from the 10 kHz step.
//!
//! Reads the release images (the board build and the `qemu` build) and follows the direct
//! call graph of the Thumb-2 code (`bl`, `b`, conditional branches into other functions) from
//! the SysTick handler, the 10 kHz task. No function on it may reach a panic symbol
//! (`core::panicking::*`, the panic handler `rust_begin_unwind`, anything named `panic`), and
//! none may call through a register (which the graph could not follow). What panic symbols
//! remain elsewhere in the image (boot-time code) is printed, with the call chain that
//! reaches each from the reset handler.
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_tests::elf::{is_panic_symbol, CallGraph, Elf};
use nemm_tests::firmware::Images;
use std::collections::BTreeSet;
use std::path::Path;

fn panic_roots(elf: &Elf) -> BTreeSet<u32> {
    elf.symbols
        .iter()
        .filter(|s| s.is_function() && is_panic_symbol(&s.name))
        .map(|s| s.start())
        .collect()
}

/// Remaining panic symbols and a chain from `Reset` to each, for the record.
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

fn check(path: &Path, what: &str) {
    let elf = Elf::read(path).expect("firmware image");
    let g = elf.call_graph();
    let systick = elf
        .function("SysTick")
        .unwrap_or_else(|| panic!("{what}: no SysTick handler in {}", path.display()))
        .start();
    let reached = g.reachable(systick);
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
        .filter(|f| g.indirect.contains(f))
        .map(|&f| g.name(f))
        .collect();
    assert!(
        indirect.is_empty(),
        "{what}: functions on the step path call through a register (not followed): {indirect:?}"
    );
    let rest = remaining(&elf, &g, &roots);
    eprintln!(
        "qemu_no_panic: {what}: {} functions reachable from SysTick, none panics; {} panic \
         symbols in the image{}",
        reached.len(),
        rest.len(),
        if rest.is_empty() {
            String::new()
        } else {
            format!(":\n    {}", rest.join("\n    "))
        }
    );
}

#[test]
fn no_panic_path_from_the_step_in_the_board_build() {
    let Some(images) = Images::from_env("qemu_no_panic") else {
        return;
    };
    check(&images.app_release, "board build");
}

#[test]
fn no_panic_path_from_the_step_in_the_qemu_build() {
    let Some(images) = Images::from_env("qemu_no_panic") else {
        return;
    };
    check(&images.app, "qemu build");
}
