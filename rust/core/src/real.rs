//! Scalar abstraction shared by the per-point algorithms: plain `f64`, or
//! [`Lanes`] of eight independent values processed together.
//!
//! The 3x3 SVD and the SNH eigensystem are chains of dependent divisions and
//! square roots, bound by their latency rather than by arithmetic. Written once
//! against [`Real`], the same code runs on `f64` (API, tests) and on eight
//! cubature points at a time in the assembly, where each operation becomes one
//! vector instruction (under the instruction-set level chosen by
//! [`crate::simd::dispatch`]) and the latency is shared by eight points.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Number of points processed together by [`Lanes`].
pub const LANES: usize = 8;

/// Arithmetic needed by the per-point algorithms.
pub trait Real: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self> {
    /// Per-value booleans.
    type Mask: Copy;
    /// The constant `x` in every value.
    fn splat(x: f64) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// `+1` or `-1` by the sign bit (so `signum(+0) = 1`), like `f64::signum`.
    fn signum(self) -> Self;
    /// `self < other`.
    fn lt(self, other: Self) -> Self::Mask;
    /// `self <= other`.
    fn le(self, other: Self) -> Self::Mask;
    /// Both masks.
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Either mask.
    fn or(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Whether any value of the mask is set.
    fn any(m: Self::Mask) -> bool;
    /// `a` where `m` is set, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
}

impl Real for f64 {
    type Mask = bool;
    #[inline(always)]
    fn splat(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn signum(self) -> Self {
        f64::signum(self)
    }
    #[inline(always)]
    fn lt(self, other: Self) -> bool {
        self < other
    }
    #[inline(always)]
    fn le(self, other: Self) -> bool {
        self <= other
    }
    #[inline(always)]
    fn and(a: bool, b: bool) -> bool {
        a && b
    }
    #[inline(always)]
    fn or(a: bool, b: bool) -> bool {
        a || b
    }
    #[inline(always)]
    fn any(m: bool) -> bool {
        m
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m {
            a
        } else {
            b
        }
    }
}

/// Eight independent values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lanes(pub [f64; LANES]);

/// Per-lane booleans as all-ones/all-zeros words, which vectorise as compare
/// results and blend masks.
#[derive(Debug, Clone, Copy)]
pub struct LaneMask([u64; LANES]);

macro_rules! lanewise {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for Lanes {
            type Output = Lanes;
            #[inline(always)]
            fn $method(self, o: Lanes) -> Lanes {
                let mut r = [0.0; LANES];
                for l in 0..LANES {
                    r[l] = self.0[l] $op o.0[l];
                }
                Lanes(r)
            }
        }
    };
}

lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Neg for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn neg(self) -> Lanes {
        Lanes(self.0.map(|x| -x))
    }
}

impl Lanes {
    #[inline(always)]
    fn compare(self, o: Lanes, f: impl Fn(f64, f64) -> bool) -> LaneMask {
        let mut m = [0u64; LANES];
        for l in 0..LANES {
            m[l] = if f(self.0[l], o.0[l]) { u64::MAX } else { 0 };
        }
        LaneMask(m)
    }
}

impl Real for Lanes {
    type Mask = LaneMask;
    #[inline(always)]
    fn splat(x: f64) -> Self {
        Lanes([x; LANES])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Lanes(self.0.map(f64::sqrt))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Lanes(self.0.map(f64::abs))
    }
    #[inline(always)]
    fn signum(self) -> Self {
        Lanes(self.0.map(|x| f64::copysign(1.0, x)))
    }
    #[inline(always)]
    fn lt(self, other: Self) -> LaneMask {
        self.compare(other, |a, b| a < b)
    }
    #[inline(always)]
    fn le(self, other: Self) -> LaneMask {
        self.compare(other, |a, b| a <= b)
    }
    #[inline(always)]
    fn and(a: LaneMask, b: LaneMask) -> LaneMask {
        let mut m = [0u64; LANES];
        for l in 0..LANES {
            m[l] = a.0[l] & b.0[l];
        }
        LaneMask(m)
    }
    #[inline(always)]
    fn or(a: LaneMask, b: LaneMask) -> LaneMask {
        let mut m = [0u64; LANES];
        for l in 0..LANES {
            m[l] = a.0[l] | b.0[l];
        }
        LaneMask(m)
    }
    #[inline(always)]
    fn any(m: LaneMask) -> bool {
        m.0.iter().fold(0, |acc, x| acc | x) != 0
    }
    #[inline(always)]
    fn select(m: LaneMask, a: Self, b: Self) -> Self {
        let mut r = [0.0; LANES];
        for l in 0..LANES {
            r[l] = f64::from_bits((a.0[l].to_bits() & m.0[l]) | (b.0[l].to_bits() & !m.0[l]));
        }
        Lanes(r)
    }
}
