//! Math written to vectorise, for the kernels' elementwise passes: e^x for x <= 0 and erf as
//! polynomials (libm's expf and erff are scalar calls that stop LLVM vectorising a loop), and
//! whether the CPU runs the kernels' AVX2 + FMA or AVX-512 builds.

/// e^x for x <= 0; exactly 0 below -87 (where e^x leaves the normal floats), -inf included, so
/// that blocked scores become probabilities of exactly 0 in the same pass.
#[inline(always)]
pub(super) fn exp_neg(x: f32) -> f32 {
    let y = if x < -87.0 { -87.0 } else { x };
    // y = n ln2 + f, n rounded to nearest by adding 1.5 * 2^23, which also leaves n in the
    // low bits of t (2^n is built from them without a float-to-int conversion, which would
    // not vectorise); ln2 in two parts (Cody & Waite) so that f keeps its precision.
    let t = y * std::f32::consts::LOG2_E + 12_582_912.0;
    let n = t - 12_582_912.0;
    let f = (y - n * 0.693_145_75) - n * 1.428_606_8e-6; // |f| <= ln2 / 2
                                                         // Taylor series of e^f to degree 7: truncation < 2e-9 on |f| <= 0.347.
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0
                    + f * (1.0 / 24.0
                        + f * (1.0 / 120.0 + f * (1.0 / 720.0 + f * (1.0 / 5040.0)))))));
    // n in [-126, 0]: (bits of t + 127) << 23 keeps exactly the exponent field n + 127.
    let e = p * f32::from_bits(t.to_bits().wrapping_add(127) << 23);
    if x < -87.0 {
        0.0
    } else {
        e
    }
}

/// erf(x) by Abramowitz & Stegun 7.1.26 (1.5e-7; within 3e-7 in f32).
#[inline(always)]
pub(super) fn erf(x: f32) -> f32 {
    erf_with(x, exp_neg(-x * x))
}

/// erf(x) as [`erf`], given e^(-x^2) (`gauss`) where the caller has it already.
#[inline(always)]
#[allow(clippy::excessive_precision)] // the published constants, as printed
pub(super) fn erf_with(x: f32, gauss: f32) -> f32 {
    let (p, a1, a2, a3, a4, a5) = (
        0.3275911f32,
        0.254829592f32,
        -0.284496736f32,
        1.421413741f32,
        -1.453152027f32,
        1.061405429f32,
    );
    let t = 1.0 / (1.0 + p * x.abs());
    let y = 1.0 - ((((a5 * t + a4) * t + a3) * t + a2) * t + a1) * t * gauss;
    y.copysign(x)
}

/// Whether this CPU runs the AVX2 + FMA builds of the kernels (checked once).
pub(super) fn avx2() -> bool {
    static AVX2: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *AVX2.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        return std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        #[cfg(not(target_arch = "x86_64"))]
        false
    })
}

/// Whether this CPU runs the AVX-512 builds of the kernels (AVX-512F with AVX2 + FMA; checked
/// once). `DIFFKFC_NO_AVX512=1` turns them off, to compare the two builds on one machine.
pub(super) fn avx512() -> bool {
    static AVX512: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *AVX512.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        return avx2()
            && std::is_x86_feature_detected!("avx512f")
            && std::env::var_os("DIFFKFC_NO_AVX512").is_none_or(|v| v.is_empty() || v == "0");
        #[cfg(not(target_arch = "x86_64"))]
        false
    })
}

/// The builds of a pass written as plain loops: AVX-512 (16 lanes), AVX2 + FMA (8 lanes) and
/// the baseline, and `$name` calling the one this CPU runs. Each element gets the same
/// operations in every build (no reassociation, no contraction), so the results are the same
/// bits; only the vector width differs.
macro_rules! elementwise_builds {
    ($vis:vis $name:ident, $generic:ident, $avx512:ident, $avx2:ident,
        ($($arg:ident: $ty:ty),*) $(-> $ret:ty)?) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx2,fma")]
        fn $avx512($($arg: $ty),*) $(-> $ret)? {
            $generic($($arg),*)
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2($($arg: $ty),*) $(-> $ret)? {
            $generic($($arg),*)
        }
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            if $crate::kernels::simd::avx512() {
                // SAFETY: the CPU has the features the function was compiled for.
                return unsafe { $avx512($($arg),*) };
            }
            #[cfg(target_arch = "x86_64")]
            if $crate::kernels::simd::avx2() {
                // SAFETY: as above.
                return unsafe { $avx2($($arg),*) };
            }
            $generic($($arg),*)
        }
    };
}

pub(super) use elementwise_builds;

/// Whether the tests can run every build here (AVX-512F, AVX2 and FMA); a notice where not.
#[cfg(all(test, target_arch = "x86_64"))]
pub(super) fn every_build_here() -> bool {
    let all = std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx2")
        && std::is_x86_feature_detected!("fma");
    if !all {
        eprintln!("notice: no AVX-512 + AVX2 + FMA here; the kernel builds are not compared");
    }
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_std_to_1e7_relative() {
        let mut worst = 0f64;
        for k in 0..200_000 {
            let x = -87.0 * k as f32 / 200_000.0;
            let (got, want) = (exp_neg(x) as f64, (x as f64).exp());
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 3e-7, "{worst}");
        assert_eq!(exp_neg(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp_neg(-87.5), 0.0);
    }

    /// erf against its series at small x and against 1 - erfc's asymptotic tail at large x,
    /// and its symmetry (libm is not used as the reference: the whole point is not to call it).
    #[test]
    fn erf_matches_its_series_and_tail() {
        let series = |x: f64| {
            // erf(x) = 2/sqrt(pi) sum (-1)^n x^(2n+1) / (n! (2n+1))
            let (mut term, mut sum) = (x, x);
            for n in 1..60 {
                term *= -x * x / n as f64;
                sum += term / (2 * n + 1) as f64;
            }
            sum * 2.0 / std::f64::consts::PI.sqrt()
        };
        let mut worst = 0f64;
        for k in 0..=300 {
            let x = k as f64 / 100.0;
            let e = (erf(x as f32) as f64 - series(x)).abs();
            worst = worst.max(e);
            assert_eq!(erf(-(x as f32)), -erf(x as f32));
        }
        assert!(worst < 3e-7, "{worst}");
        assert!((erf(6.0) - 1.0).abs() < 1e-7);
    }
}
