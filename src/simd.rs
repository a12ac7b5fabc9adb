//! Run-time dispatch to an AVX2 + FMA build of a hot loop (`vectorised_fn!`), used by the CPU
//! engine (`sweep/cpu/`) and fusion (`fusion/integrate.rs`). Imports nothing of the crate.

/// `floor(t)` as an integer for `0 <= t < 2^22`, in float and integer lane operations that
/// vectorise: rounded to an integer by adding and taking away 2^23, less one where that
/// rounded up, then the integer read from the low mantissa bits of the floor plus 2^23. The
/// saturating `as` casts, which must also handle NaN and values out of range, compile into
/// scalar conversions with compares and branches per lane. Used by fusion's voxel update and
/// colour average and by the WGSL engine's map unpacking.
#[inline(always)]
pub fn floor_small(t: f32) -> i32 {
    const MAGIC: f32 = 8_388_608.0;
    let near = (t + MAGIC) - MAGIC;
    let floor = near - if near > t { 1.0 } else { 0.0 };
    (floor + MAGIC).to_bits() as i32 - MAGIC.to_bits() as i32
}

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
