//! Run-time dispatch to an AVX2 + FMA build of a hot loop (`vectorised_fn!`), used by the CPU
//! engine (`sweep/cpu/`) and fusion (`fusion/integrate.rs`). Imports nothing of the crate.

/// Whether the CPU has AVX2 and FMA (cached by std).
#[inline(always)]
pub fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines a function twice, for the portable baseline and for AVX2 + FMA, and picks one at
/// run time. The hot loops are plain loops that the compiler vectorises (8 f32 / 16 u16 lanes
/// with AVX2); everything the body calls that should profit must be `#[inline(always)]`. No
/// result changes: Rust never contracts a multiply and an add into an FMA by itself.
macro_rules! vectorised_fn {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body($($arg: $ty),*) $(-> $ret)? $body
            // One of the crate's two unsafe blocks (the other: process_env's mallopt):
            // calling the AVX2 + FMA build of the body.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            {
                #[target_feature(enable = "avx2,fma")]
                fn avx2($($arg: $ty),*) $(-> $ret)? {
                    body($($arg),*)
                }
                if $crate::simd::has_avx2_fma() {
                    // SAFETY: the CPU has AVX2 and FMA, checked just above.
                    return unsafe { avx2($($arg),*) };
                }
            }
            body($($arg),*)
        }
    };
}
pub(crate) use vectorised_fn;
