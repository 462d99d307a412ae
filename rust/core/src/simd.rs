//! Runtime selection of the instruction set for the hot loops.
//!
//! Wheels are built for baseline x86-64 (SSE2, no FMA), which would leave most of
//! a modern core idle in the per-point loops. A kernel implements [`WithMadd`];
//! [`dispatch`] runs it inside a function compiled with AVX-512 or AVX2+FMA when
//! the CPU has them, so everything the kernel inlines is vectorised for that
//! level. The [`Madd`] parameter makes `a * b + c` a fused multiply-add only
//! where the hardware has one: `f64::mul_add` without FMA is a slow libm call.

/// Multiply-add flavour of a kernel instantiation.
pub trait Madd: Copy {
    /// `a * b + c`.
    fn madd(a: f64, b: f64, c: f64) -> f64;
}

/// Separate multiply and add (targets without FMA).
#[derive(Clone, Copy)]
pub struct Separate;

/// Fused multiply-add.
#[derive(Clone, Copy)]
pub struct Fused;

impl Madd for Separate {
    #[inline(always)]
    fn madd(a: f64, b: f64, c: f64) -> f64 {
        a * b + c
    }
}

impl Madd for Fused {
    #[inline(always)]
    fn madd(a: f64, b: f64, c: f64) -> f64 {
        a.mul_add(b, c)
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
    kernel.run::<Fused>()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_avx2<K: WithMadd>(kernel: K) -> K::Output {
    kernel.run::<Fused>()
}
