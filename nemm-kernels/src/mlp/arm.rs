//! Cortex-M4F (FPv4-SP) kernels of [`super::CompiledScaler`]: the whole network from the
//! state input `u` to the raw output `z` in one `asm!` block per width (`H` = 8, 16, 32).
//!
//! # Why `unsafe` and `asm!`
//!
//! Measured with the firmware's `nemm-bench` (QEMU `mps2-an386`, `-icount shift=0`, example
//! NEMM `H = 16, L = 5`, RK4, exact mode): the portable code costs 156,466 instructions per
//! step, ~15 instructions per multiply-accumulate, because stable Rust has no `no_std`
//! fused multiply-add intrinsic and refuses the `sreg` register class on this target
//! (`thumbv7em-none-eabihf` has `vfp4d16sp`, which Rust does not map to its `vfp2` feature),
//! so every `vfma.f32` from [`crate::math::fma`] moves its operands through core registers.
//! These kernels keep everything in the FPU: `vldmia` streams up to 12 weights per
//! instruction, a layer's 16 inputs stay in `s16..s31`, each multiply-accumulate is one
//! `vfma.f32`, the LayerNorm output goes straight into the registers the next layer reads.
//! The same step takes 15,501 instructions (RK3: 11,659; 1,796 per network evaluation, within
//! ~4 % of the 1,216 `vfma` + 160 `vmul` + bookkeeping this arithmetic needs). Details, cycle
//! estimates and the per-change table: `nemm-firmware/README.md`, "Real time / instruction
//! figures".
//!
//! Explicit FPU register clobbers (`out("d0") _` ...) are accepted where the `sreg` class is
//! not (rustc skips the feature check for clobbers), so the compiler itself saves the
//! callee-saved `d8..d15` and keeps none of its own values in `s0..s15` across the block.
//!
//! # Same bits as the portable code
//!
//! Each kernel performs the operations of [`super::CompiledScaler`]'s "exact arithmetic" in
//! the same order, with the same IEEE 754 single-precision operations:
//!
//! | portable code (host: `libm`)            | kernel                                      |
//! |-----------------------------------------|---------------------------------------------|
//! | `t_i = fma(w_i, u, b_i)` (layer 1)      | `vfma.f32 t_i, w_i, u` with `t_i = b_i`     |
//! | `acc = b_i; acc = fma(W_ij, a_j, acc)`, `j` ascending | `vfma.f32 acc, W_ij, a_j`, `j` ascending, from `acc = b_i` |
//! | `var = fma(t_i, t_i, var)`, `i` ascending, from `0.0`, then `* (1/H)` | `vfma.f32 var, t_i, t_i` from `0.0`, `vmul.f32` |
//! | `r = 1.0 / sqrt(var + eps)`             | `vadd.f32`, `vsqrt.f32`, `vdiv.f32` from `1.0` |
//! | `y_i = fma(gamma_i, t_i * r, beta_i)`   | `vmul.f32`, then `vfma.f32 y_i, gamma_i, tr_i` from `y_i = beta_i` |
//! | `a_i = if y_i >= 0 { y_i } else { 0.01 * y_i }` | `vmul.f32` by `0.01` when the sign bit of `y_i` is set (see below) |
//! | `z = fma-chain from b_o over w_o_i * a_i` | `vfma.f32 z, w_o_i, a_i`, `i` ascending   |
//!
//! `vfma.f32` rounds once (fused), `vsqrt.f32` and `vdiv.f32` are correctly rounded, the
//! FPSCR is left at its reset state (round to nearest, no flush-to-zero, no default NaN), so
//! every result is the correctly rounded value the portable code computes with `libm::fmaf`,
//! `libm::sqrtf` and Rust's `f32` operators.
//!
//! LeakyReLU by sign bit: `y >= 0.0` is false exactly for the values with the sign bit set
//! (negative numbers and `-0.0`, for which `0.01 * -0.0 = -0.0` is the same bits as keeping
//! it) and for NaN (which stays NaN either way; the estimator never lets one through). The
//! kernel moves two outputs to core registers with one `vmov`, one `teq ry, rx, lsr #32`
//! sets C = sign(x) and N = sign(y), and two one-instruction IT blocks do the conditional
//! multiplies: 3 instructions per element instead of `vcmp`, `vmrs`, `it`, `vmul`.
//!
//! # Layout and scratch
//!
//! The kernels read the compiled weight vector exactly as laid out by
//! [`super::CompiledScaler::compile`] (`H x H` matrices in column blocks of 16), from its
//! first to its last element, and the four constants `[1/H, eps, slope, 0.0]`. [`raw`]
//! checks the length against [`super::compiled_len`] before entering a kernel. The
//! pre-activations (and for `H = 32` the activations) pass through a scratch array on the
//! caller's stack.
//!
//! Requires an FPU with fused multiply-add (VFPv4 or later: Cortex-M4F, M7, M33, M55); the
//! `cfg` that includes this module is bare-metal hard-float Arm.

use super::{compiled_len, MAX_LAYERS};
use core::arch::asm;
use core::mem::MaybeUninit;

/// The raw network output `z` computed by the kernel for width `h`, or `None` if there is no
/// kernel for `h` (or the weight vector does not have the compiled length, which `compile`
/// rules out): the caller then runs the portable code.
#[inline(always)]
pub(super) fn raw(h: usize, layers: usize, w: &[f32], consts: &[f32; 4], u: f32) -> Option<f32> {
    if !(1..=MAX_LAYERS).contains(&layers) || Some(w.len()) != compiled_len(h, layers) {
        return None;
    }
    match h {
        8 => Some(raw8(w, layers, consts, u)),
        16 => Some(raw16(w, layers, consts, u)),
        32 => Some(raw32(w, layers, consts, u)),
        _ => None,
    }
}

/// Assembler macros shared by the kernels (LLVM's integrated assembler, `.altmacro` for the
/// `%(expr)` register arithmetic). Purged again by `macros_end!` so that the block can be
/// emitted more than once per object file.
///
/// - `nemm_mv p, nr, nc, acc, x, w, nw`: rows `0..nr` of an `nr x nc` block streamed from
///   `[p]` (post-increment) through the chunk registers `s(w) .. s(w + nw - 1)` (one `vldmia`
///   per chunk); row `i`: `s(acc + i) = fma(W_ij, s(x + j), s(acc + i))`, `j` ascending.
/// - `nemm_dot d, a, b, n`: `s(d) = fma(s(a + k), s(b + k), s(d))`, `k` ascending.
/// - `nemm_axpy a, w, x, n`: `s(a + k) = fma(s(w + k), s(x), s(a + k))`.
/// - `nemm_ln n, t, g, y, r, sl`: `n` (even) LayerNorm outputs:
///   `s(y + k) = leaky(fma(s(g + k), s(t + k) * s(r), s(y + k)))` with slope `s(sl)`;
///   `s(t + k)` is overwritten; uses the core registers `{ra}`, `{rb}`.
/// - `nemm_ln16 pt, pb`: the 16 LayerNorm outputs of a 16-input block into `s16..s31`
///   (holding the betas): pre-activations from `[pt]`, gammas from `[pb]` (both
///   post-incremented), `1 / sqrt(var + eps)` in `s15`, slope in `s14`; uses `s0..s11`.
/// - `nemm_rnorm v, k0, k1, k2`: `s(v) = 1 / sqrt(s(v) * (1/H) + eps)` with the constants
///   `[1/H, eps, slope]` loaded from `[{c}]` into `s(k0), s(k1), s(k2)` (`s(k0)` is
///   overwritten by `1.0`).
macro_rules! macros_begin {
    () => {
        r#"
.altmacro
.macro nemm_fma qd, qn, qm
  vfma.f32 s\qd, s\qn, s\qm
.endm
.macro nemm_vld qp, qa, qb
  vldmia \qp!, {{s\qa-s\qb}}
.endm
.macro nemm_mv qp, qr, qc, qacc, qx, qw, qnw
  .set .Lnemm_m, 0
  .rept (\qr) * (\qc)
    .if (.Lnemm_m % (\qnw)) == 0
      .if ((\qr) * (\qc) - .Lnemm_m) < (\qnw)
        nemm_vld \qp, \qw, %((\qw) - 1 + (\qr) * (\qc) - .Lnemm_m)
      .else
        nemm_vld \qp, \qw, %((\qw) + (\qnw) - 1)
      .endif
    .endif
    nemm_fma %((\qacc) + .Lnemm_m / (\qc)), %((\qw) + .Lnemm_m % (\qnw)), %((\qx) + .Lnemm_m % (\qc))
    .set .Lnemm_m, .Lnemm_m + 1
  .endr
.endm
.macro nemm_dot qd, qa, qb, qn
  .set .Lnemm_k, 0
  .rept \qn
    nemm_fma \qd, %((\qa) + .Lnemm_k), %((\qb) + .Lnemm_k)
    .set .Lnemm_k, .Lnemm_k + 1
  .endr
.endm
.macro nemm_axpy qa, qw, qx, qn
  .set .Lnemm_k, 0
  .rept \qn
    nemm_fma %((\qa) + .Lnemm_k), %((\qw) + .Lnemm_k), \qx
    .set .Lnemm_k, .Lnemm_k + 1
  .endr
.endm
.macro nemm_ln2 qt0, qt1, qg0, qg1, qy0, qy1, qr, qs
  vmul.f32 s\qt0, s\qt0, s\qr
  vmul.f32 s\qt1, s\qt1, s\qr
  vfma.f32 s\qy0, s\qg0, s\qt0
  vfma.f32 s\qy1, s\qg1, s\qt1
  vmov {ra}, {rb}, s\qy0, s\qy1
  teq {rb}, {ra}, lsr #32
  it cs
  vmulcs.f32 s\qy0, s\qy0, s\qs
  it mi
  vmulmi.f32 s\qy1, s\qy1, s\qs
.endm
.macro nemm_ln qn, qt, qg, qy, qr, qs
  .set .Lnemm_l, 0
  .rept (\qn) / 2
    nemm_ln2 %((\qt) + .Lnemm_l), %((\qt) + .Lnemm_l + 1), %((\qg) + .Lnemm_l), %((\qg) + .Lnemm_l + 1), %((\qy) + .Lnemm_l), %((\qy) + .Lnemm_l + 1), \qr, \qs
    .set .Lnemm_l, .Lnemm_l + 2
  .endr
.endm
.macro nemm_ln16 qpt, qpb
  vldmia \qpt!, {{s0-s5}}
  vldmia \qpb!, {{s6-s11}}
  nemm_ln 6, 0, 6, 16, 15, 14
  vldmia \qpt!, {{s0-s5}}
  vldmia \qpb!, {{s6-s11}}
  nemm_ln 6, 0, 6, 22, 15, 14
  vldmia \qpt!, {{s0-s3}}
  vldmia \qpb!, {{s6-s9}}
  nemm_ln 4, 0, 6, 28, 15, 14
.endm
.macro nemm_rnorm qv, qk0, qk1, qk2
  vldmia {c}, {{s\qk0-s\qk2}}
  vmul.f32 s\qv, s\qv, s\qk0
  vadd.f32 s\qv, s\qv, s\qk1
  vsqrt.f32 s\qv, s\qv
  vmov.f32 s\qk0, #1.0
  vdiv.f32 s\qv, s\qk0, s\qv
.endm
"#
    };
}

macro_rules! macros_end {
    () => {
        r#"
.purgem nemm_fma
.purgem nemm_vld
.purgem nemm_mv
.purgem nemm_dot
.purgem nemm_axpy
.purgem nemm_ln2
.purgem nemm_ln
.purgem nemm_ln16
.purgem nemm_rnorm
.noaltmacro
"#
    };
}

/// One kernel: `fn $name(w, layers, consts, u) -> f32` running the width's instructions
/// `$body` between the shared assembler macros, with `$scratch` floats of scratch on the
/// stack. The operands are the same for every width: `{w}` the weights (advanced by the
/// block), `{n}` the hidden layers after the first (counted down), `{u}` the input bits in and
/// the output bits out, `{c}` the 4 constants, `{s}` the scratch, `{b}`, `{t}`, `{ra}`, `{rb}`
/// free core registers, and every FPU register clobbered.
macro_rules! kernel {
    ($(#[$doc:meta])* fn $name:ident, scratch = $scratch:literal, $body:literal) => {
        $(#[$doc])*
        #[inline(never)]
        fn $name(w: &[f32], layers: usize, consts: &[f32; 4], u: f32) -> f32 {
            let mut scratch = MaybeUninit::<[f32; $scratch]>::uninit();
            let z: u32;
            // SAFETY: `raw` checked `w.len() == compiled_len(H, layers)` and
            // `1 <= layers <= MAX_LAYERS`. The block reads `w` from its first to its last
            // element in the compiled layout (the kernel's "Reads" above) and the 4
            // constants, and writes and reads back only the `$scratch` floats of `scratch`.
            // Every FPU register it touches is declared clobbered (`d0..d15` = `s0..s31`);
            // the core registers are operands; it does not use the stack; it changes the
            // APSR flags (no `preserves_flags`).
            unsafe {
                asm!(
                    macros_begin!(),
                    $body,
                    macros_end!(),
                    w = inout(reg) w.as_ptr() => _,
                    n = inout(reg) layers - 1 => _,
                    u = inout(reg) u.to_bits() => z,
                    c = in(reg) consts.as_ptr(),
                    s = in(reg) scratch.as_mut_ptr(),
                    b = out(reg) _,
                    t = out(reg) _,
                    ra = out(reg) _,
                    rb = out(reg) _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                    out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                    out("d12") _, out("d13") _, out("d14") _, out("d15") _,
                    options(nostack),
                );
            }
            f32::from_bits(z)
        }
    };
}

kernel! {
    /// `H = 16`: inputs of a layer in `s16..s31`; rows in groups of 4 (accumulators `s0..s3`,
    /// weights streamed through `s4..s14`, 6 `vldmia` per 64 weights), `var` in `s15`.
    ///
    /// Reads layer 1: 4 x 16, each further layer 256 + 3 x 16, output 17; scratch: the 16
    /// pre-activations.
    fn raw16, scratch = 16,
    r#"
    vmov s8, {u}
    vldr s15, [{c}, #12]
    add {b}, {w}, #64
    vldmia {w}!, {{s0-s7}}
    vldmia {b}!, {{s16-s23}}
    nemm_axpy 16, 0, 8, 8
    vldmia {w}, {{s0-s7}}
    vldmia {b}!, {{s24-s31}}
    nemm_axpy 24, 0, 8, 8
    nemm_dot 15, 16, 16, 16
    vstmia {s}, {{s16-s31}}
    b 3f
2:
    mov {w}, {b}
    add {b}, {w}, #1024
    mov {t}, {s}
    vldr s15, [{c}, #12]
    .rept 4
    vldmia {b}!, {{s0-s3}}
    nemm_mv {w}, 4, 16, 0, 16, 4, 11
    nemm_dot 15, 0, 0, 4
    vstmia {t}!, {{s0-s3}}
    .endr
3:
    nemm_rnorm 15, 12, 13, 14
    add {t}, {b}, #64
    vldmia {t}, {{s16-s31}}
    mov {t}, {s}
    nemm_ln16 {t}, {b}
    add {b}, {b}, #64
    subs {n}, {n}, #1
    bpl 2b
    vldmia {b}, {{s1-s15}}
    vldr s0, [{b}, #64]
    nemm_dot 0, 1, 16, 15
    vldr s1, [{b}, #60]
    vfma.f32 s0, s1, s31
    vmov {u}, s0
"#
}

kernel! {
    /// `H = 8`: inputs in `s24..s31`; all 8 rows at once (accumulators `s0..s7`, two rows of
    /// weights per `vldmia` into `s8..s23`); `var` in `s23` (after the rows).
    ///
    /// Reads layer 1: 4 x 8, each further layer 64 + 3 x 8, output 9; scratch: the 8
    /// pre-activations.
    fn raw8, scratch = 8,
    r#"
    vmov s16, {u}
    vldr s23, [{c}, #12]
    vldmia {w}!, {{s0-s15}}
    nemm_axpy 8, 0, 16, 8
    nemm_dot 23, 8, 8, 8
    vstmia {s}, {{s8-s15}}
    mov {b}, {w}
    b 3f
2:
    mov {w}, {b}
    add {b}, {w}, #256
    vldmia {b}!, {{s0-s7}}
    nemm_mv {w}, 8, 8, 0, 24, 8, 16
    vldr s23, [{c}, #12]
    nemm_dot 23, 0, 0, 8
    vstmia {s}, {{s0-s7}}
3:
    nemm_rnorm 23, 20, 21, 22
    add {t}, {b}, #32
    vldmia {t}, {{s24-s31}}
    vldmia {s}, {{s0-s7}}
    vldmia {b}!, {{s8-s15}}
    nemm_ln 8, 0, 8, 24, 23, 22
    add {b}, {b}, #32
    subs {n}, {n}, #1
    bpl 2b
    vldmia {b}, {{s0-s8}}
    nemm_dot 8, 0, 24, 8
    vmov {u}, s8
"#
}

kernel! {
    /// `H = 32`: two passes of 16 inputs each (column blocks), inputs in `s16..s31`, partial
    /// sums and activations through the scratch (`t[0..32]`, `act[0..32]`); rows in groups of 4
    /// as for `H = 16`; `var` in `s15` during the second pass.
    ///
    /// Reads layer 1: 4 x 32, each further layer 1024 + 3 x 32 with the matrix in two
    /// column blocks, output 33; scratch: pre-activations at `[0, 32)`, activations at
    /// `[32, 64)`.
    fn raw32, scratch = 64,
    r#"
    vmov s8, {u}
    vldr s15, [{c}, #12]
    add {b}, {w}, #128
    mov {t}, {s}
    .rept 4
    vldmia {w}!, {{s0-s7}}
    vldmia {b}!, {{s16-s23}}
    nemm_axpy 16, 0, 8, 8
    nemm_dot 15, 16, 16, 8
    vstmia {t}!, {{s16-s23}}
    .endr
    b 3f
2:
    mov {w}, {b}
    add {b}, {w}, #4096
    add {t}, {s}, #128
    vldmia {t}, {{s16-s31}}
    mov {t}, {s}
    .rept 8
    vldmia {b}!, {{s0-s3}}
    nemm_mv {w}, 4, 16, 0, 16, 4, 12
    vstmia {t}!, {{s0-s3}}
    .endr
    add {t}, {s}, #192
    vldmia {t}, {{s16-s31}}
    mov {t}, {s}
    vldr s15, [{c}, #12]
    .rept 8
    vldmia {t}, {{s0-s3}}
    nemm_mv {w}, 4, 16, 0, 16, 4, 11
    nemm_dot 15, 0, 0, 4
    vstmia {t}!, {{s0-s3}}
    .endr
3:
    nemm_rnorm 15, 12, 13, 14
    mov {t}, {s}
    .rept 2
    add {ra}, {b}, #128
    vldmia {ra}, {{s16-s31}}
    nemm_ln16 {t}, {b}
    add {ra}, {t}, #64
    vstmia {ra}, {{s16-s31}}
    .endr
    add {b}, {b}, #128
    subs {n}, {n}, #1
    bpl 2b
    vldr s0, [{b}, #128]
    add {t}, {s}, #128
    vldmia {t}!, {{s16-s31}}
    vldmia {b}!, {{s1-s15}}
    nemm_dot 0, 1, 16, 15
    vldmia {b}!, {{s1}}
    vfma.f32 s0, s1, s31
    vldmia {t}, {{s16-s31}}
    vldmia {b}!, {{s1-s15}}
    nemm_dot 0, 1, 16, 15
    vldr s1, [{b}]
    vfma.f32 s0, s1, s31
    vmov {u}, s0
"#
}
