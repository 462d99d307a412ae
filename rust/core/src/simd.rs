//! Runtime selection of the instruction set for the hot loops.
//!
//! Wheels are built for baseline x86-64 (SSE2, no FMA), which would leave most of
//! a modern core idle in the per-point loops. A kernel implements [`WithMadd`];
//! [`dispatch`] runs it inside a function compiled with AVX-512 or AVX2+FMA when
//! the CPU has them, so everything the kernel inlines is vectorised for that
//! level. The [`Madd`] parameter makes `a * b + c` a fused multiply-add only
//! where the hardware has one: `f64::mul_add` without FMA is a slow libm call.
//!
//! [`Madd::madd8`] is the same on eight values at once (one vector of eight
//! lanes, or two of four) through explicit intrinsics. The lane-packed kernels
//! loop over many independent eight-lane blocks; written as plain loops, the
//! compiler's loop vectoriser would rather vectorise across the blocks, with
//! gathers, than within each block. The intrinsics pin the vectors down.

use crate::real::LANES;

/// One value per lane.
pub type F8 = [f64; LANES];

// The intrinsics below hold eight lanes in one AVX-512 or two AVX2 vectors.
const _: () = assert!(LANES == 8);

/// Sum of the lanes, in a fixed pairwise order (the same in every kernel, so
/// that results do not depend on which kernel reduced them).
#[inline(always)]
pub fn lane_sum(a: &F8) -> f64 {
    ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7]))
}

/// Multiply-add flavour of a kernel instantiation (one per instruction-set level).
pub trait Madd: Copy {
    /// `a * b + c`, fused (one rounding) unless the flavour says otherwise.
    #[inline(always)]
    fn madd(a: f64, b: f64, c: f64) -> f64 {
        a.mul_add(b, c)
    }
    /// `a * b + c` lane by lane.
    #[inline(always)]
    fn madd8(a: &F8, b: &F8, c: F8) -> F8 {
        let mut r = c;
        for l in 0..LANES {
            r[l] = Self::madd(a[l], b[l], c[l]);
        }
        r
    }
    /// `a * b + c` lane by lane with a scalar `a`.
    #[inline(always)]
    fn madd8_splat(a: f64, b: &F8, c: F8) -> F8 {
        Self::madd8(&[a; LANES], b, c)
    }
}

/// Separate multiply and add (targets without FMA).
#[derive(Clone, Copy)]
pub struct Separate;

/// Fused multiply-add, eight lanes as two AVX2 vectors (x86-64 only, inside
/// [`dispatch`]'s AVX2 function).
#[derive(Clone, Copy)]
pub struct Avx2;

/// Fused multiply-add, eight lanes as one AVX-512 vector (x86-64 only, inside
/// [`dispatch`]'s AVX-512 function).
#[derive(Clone, Copy)]
pub struct Avx512;

impl Madd for Separate {
    #[inline(always)]
    fn madd(a: f64, b: f64, c: f64) -> f64 {
        a * b + c
    }
}

#[cfg(target_arch = "x86_64")]
impl Madd for Avx2 {
    #[inline(always)]
    fn madd8(a: &F8, b: &F8, c: F8) -> F8 {
        use std::arch::x86_64::{_mm256_fmadd_pd, _mm256_loadu_pd, _mm256_storeu_pd};
        let mut r = [0.0; LANES];
        // SAFETY: this type is only instantiated inside `run_avx2`, compiled with
        // AVX2 and FMA after their detection; the pointers cover 8 values each.
        unsafe {
            for h in [0, 4] {
                let v = _mm256_fmadd_pd(_mm256_loadu_pd(a.as_ptr().add(h)), _mm256_loadu_pd(b.as_ptr().add(h)), _mm256_loadu_pd(c.as_ptr().add(h)));
                _mm256_storeu_pd(r.as_mut_ptr().add(h), v);
            }
        }
        r
    }
}

#[cfg(target_arch = "x86_64")]
impl Madd for Avx512 {
    #[inline(always)]
    fn madd8(a: &F8, b: &F8, c: F8) -> F8 {
        use std::arch::x86_64::{_mm512_fmadd_pd, _mm512_loadu_pd, _mm512_storeu_pd};
        let mut r = [0.0; LANES];
        // SAFETY: this type is only instantiated inside `run_avx512`, compiled with
        // AVX-512F after its detection; the pointers cover 8 values each.
        unsafe {
            let v = _mm512_fmadd_pd(_mm512_loadu_pd(a.as_ptr()), _mm512_loadu_pd(b.as_ptr()), _mm512_loadu_pd(c.as_ptr()));
            _mm512_storeu_pd(r.as_mut_ptr(), v);
        }
        r
    }
}

/// A computation to run at the best available instruction-set level. `run`
/// must be `#[inline(always)]`, as must the hot helpers it calls.
pub trait WithMadd {
    /// What the computation returns.
    type Output;
    /// The computation, generic over the multiply-add flavour.
    fn run<M: Madd>(self) -> Self::Output;
}

/// Runs `kernel` compiled for the best instruction set of this CPU.
#[inline]
pub fn dispatch<K: WithMadd>(kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the features the function is compiled for were detected above.
            return unsafe { run_avx512(kernel) };
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: as above.
            return unsafe { run_avx2(kernel) };
        }
    }
    kernel.run::<Separate>()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx2,fma")]
unsafe fn run_avx512<K: WithMadd>(kernel: K) -> K::Output {
    kernel.run::<Avx512>()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_avx2<K: WithMadd>(kernel: K) -> K::Output {
    kernel.run::<Avx2>()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lane_multiply_adds_agree() {
        let a: F8 = std::array::from_fn(|l| l as f64 * 0.5 - 1.0);
        let b: F8 = std::array::from_fn(|l| 3.0 - l as f64);
        let c: F8 = std::array::from_fn(|l| l as f64 * l as f64);
        let expected: F8 = std::array::from_fn(|l| a[l] * b[l] + c[l]);
        struct Check(F8, F8, F8);
        impl WithMadd for Check {
            type Output = (F8, F8);
            #[inline(always)]
            fn run<M: Madd>(self) -> (F8, F8) {
                (M::madd8(&self.0, &self.1, self.2), M::madd8_splat(2.0, &self.1, self.2))
            }
        }
        let (r, s) = dispatch(Check(a, b, c));
        assert_eq!(r, expected);
        assert_eq!(s, std::array::from_fn::<f64, 8, _>(|l| 2.0 * b[l] + c[l]));
    }
}
