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

/// The widest build that `vectorised_fn!` may pick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Tier {
    /// The portable build.
    Portable = 1,
    /// AVX2 + FMA.
    Avx2 = 2,
    /// AVX-512 (F, BW, VL, DQ, VPOPCNTDQ).
    Avx512 = 3,
}

/// The cap set by [`cap`] (0: none).
static CAP: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

/// Caps ([`Some`]) or frees ([`None`]) the builds picked from now on, for tests and benches
/// that compare the builds on one machine (they give the same floats, so threads that pick up
/// the cap midway are harmless).
pub fn cap(tier: Option<Tier>) {
    CAP.store(
        tier.map_or(0, |t| t as u8),
        std::sync::atomic::Ordering::Relaxed,
    );
}

/// Whether [`cap`] allows `tier`.
#[inline(always)]
fn allowed(tier: Tier) -> bool {
    let cap = CAP.load(std::sync::atomic::Ordering::Relaxed);
    cap == 0 || tier as u8 <= cap
}

/// Whether the CPU has AVX2 and FMA (cached by std) and [`cap`] allows them.
#[inline(always)]
pub fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        allowed(Tier::Avx2)
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU has AVX-512 F, BW, VL, DQ and VPOPCNTDQ besides AVX2 and FMA (cached by
/// std) and [`cap`] allows them.
#[inline(always)]
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        allowed(Tier::Avx512)
            && has_avx2_fma()
            && std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512vpopcntdq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines a function three times, for the portable baseline, for AVX2 + FMA and for AVX-512
/// (F, BW, VL, DQ, VPOPCNTDQ: 16 f32 lanes, a popcount per lane), and picks the widest the CPU
/// has at run time. The hot loops are plain loops that the compiler vectorises; everything the
/// body calls that should profit must be `#[inline(always)]`. No result changes: Rust never
/// contracts a multiply and an add into an FMA by itself, and lanes are lanes at any width.
///
/// `vectorised_fn! { avx2: fn ... }` leaves out the AVX-512 build: SGM's path steps are made
/// for 16 u16 lanes (`sgm::LANES`) and ran at half speed in 512-bit registers (`bench`, demo
/// and ring, 2-core AMD EPYC).
macro_rules! vectorised_fn {
    (avx2: $(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $crate::simd::vectorised_fn!(@tiers false; $(#[$meta])* $vis fn $name($($arg: $ty),*) $(-> $ret)? $body);
    };
    (@tiers $wide:tt; $(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body($($arg: $ty),*) $(-> $ret)? $body
            // One of the crate's two unsafe blocks (the other: process_env's mallopt):
            // calling the AVX-512 or AVX2 + FMA build of the body.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code, reason = "the call of a build whose CPU features were checked just before")]
            {
                $crate::simd::vectorised_fn!(@avx512 $wide; ($($arg: $ty),*) $(-> $ret)?);
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
    // The AVX-512 build of `body` and its call, inside the function's dispatch (or nothing).
    (@avx512 true; ($($arg:ident: $ty:ty),*) $(-> $ret:ty)?) => {
        #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx512vpopcntdq,avx2,fma")]
        fn avx512($($arg: $ty),*) $(-> $ret)? {
            body($($arg),*)
        }
        if $crate::simd::has_avx512() {
            // SAFETY: the CPU has these AVX-512 subsets, AVX2 and FMA, checked just above.
            return unsafe { avx512($($arg),*) };
        }
    };
    (@avx512 false; ($($arg:ident: $ty:ty),*) $(-> $ret:ty)?) => {};
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $crate::simd::vectorised_fn!(@tiers true; $(#[$meta])* $vis fn $name($($arg: $ty),*) $(-> $ret)? $body);
    };
}
pub(crate) use vectorised_fn;
