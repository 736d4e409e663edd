//! [`Lanes`]: the trainer's batch of windows as one [`Lane`] (feature `reverse`).

use super::{Lane, Scalar};
use core::ops::{Add, Div, Mul, Neg, Sub};

/// `N` values of `T` advanced in lock step (the trainer's batch of windows). The operators
/// work element-wise; fixed-size loops the compiler vectorises.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lanes<T, const N: usize>(pub [T; N]);

impl<T: Scalar, const N: usize> Default for Lanes<T, N> {
    fn default() -> Self {
        Self([T::from_f32(0.0); N])
    }
}

impl<T: Scalar, const N: usize> Lanes<T, N> {
    /// Element-wise `f(a_k, b_k)`.
    #[inline(always)]
    fn zip_with(self, b: Self, f: impl Fn(T, T) -> T) -> Self {
        let mut out = self.0;
        for (o, bk) in out.iter_mut().zip(b.0) {
            *o = f(*o, bk);
        }
        Self(out)
    }

    /// Element-wise `f(a_k)`.
    #[inline(always)]
    fn map(self, f: impl Fn(T) -> T) -> Self {
        let mut out = self.0;
        for o in out.iter_mut() {
            *o = f(*o);
        }
        Self(out)
    }
}

macro_rules! lanes_binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<T: Scalar, const N: usize> $tr for Lanes<T, N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, b: Self) -> Self {
                self.zip_with(b, |x, y| x $op y)
            }
        }
    };
}
lanes_binop!(Add, add, +);
lanes_binop!(Sub, sub, -);
lanes_binop!(Mul, mul, *);
lanes_binop!(Div, div, /);

impl<T: Scalar, const N: usize> Neg for Lanes<T, N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|x| -x)
    }
}

impl<T: Scalar, const N: usize> Lane for Lanes<T, N> {
    type Scalar = T;
    #[inline(always)]
    fn splat(v: T) -> Self {
        Self([v; N])
    }
    #[inline(always)]
    fn fma(a: Self, b: Self, c: Self) -> Self {
        let mut out = c.0;
        for ((o, ak), bk) in out.iter_mut().zip(a.0).zip(b.0) {
            *o = T::fma(ak, bk, *o);
        }
        Self(out)
    }
    #[inline(always)]
    fn exp(x: Self) -> Self {
        x.map(T::exp)
    }
    #[inline(always)]
    fn sqrt(x: Self) -> Self {
        x.map(T::sqrt)
    }
    #[inline(always)]
    fn rsqrt(x: Self) -> Self {
        x.map(T::rsqrt)
    }
    #[inline(always)]
    fn select_nonneg(test: Self, if_nonneg: Self, otherwise: Self) -> Self {
        let zero = T::from_f32(0.0);
        let mut out = otherwise.0;
        for ((o, t), y) in out.iter_mut().zip(test.0).zip(if_nonneg.0) {
            if t >= zero {
                *o = y;
            }
        }
        Self(out)
    }
    #[inline(always)]
    fn sum(x: Self) -> T {
        x.0.into_iter().fold(T::from_f32(0.0), |s, v| s + v)
    }
}
