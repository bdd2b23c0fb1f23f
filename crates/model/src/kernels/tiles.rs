//! The register tiles of the flash attention kernel (`flash.rs`): a block's three products
//! (scores, weighted values, the weights' outer products into dK and dV), as plain loops for any
//! CPU, as AVX2 + FMA intrinsics and as AVX-512 intrinsics (16 lanes: a chunk of [`W`] keys, or
//! a 16-wide head's row, is one register). LLVM does not vectorise the plain loops' tiles (it
//! unrolls them into scalar code), so the fast ones are written out.

/// Keys per register chunk of a score row.
pub(super) const W: usize = 16;

/// The three products of a block, on a CPU's vector registers.
pub(super) trait Lanes {
    /// Query rows per block: as many as the build's registers hold the tiles of.
    const R: usize;
    /// out[r][j] = scale * a[r] . bt[.][j] for the block's R rows `a` ([R, P]) and every column
    /// of `bt` ([P, n16]); out is [R, n16].
    fn dots<const P: usize>(a: &[f32], bt: &[f32], n16: usize, scale: f32, out: &mut [f32]);
    /// out[r] = sum_j w[r][j] m[j] for the block's weights `w` ([R, n16]) over the first `n`
    /// rows of `m` ([n, P]); out is [R, P].
    fn mix<const P: usize>(w: &[f32], n16: usize, n: usize, m: &[f32], out: &mut [f32]);
    /// acc[j] += sum_r w[r][j] x[r] for the first `n` rows of acc ([n, P]), the block's weights
    /// `w` ([R, n16]) and rows `x` ([R, P]).
    fn spread<const P: usize>(w: &[f32], n16: usize, n: usize, x: &[f32], acc: &mut [f32]);
}

/// Plain loops: any CPU (and the reference the intrinsics builds are tested against), in
/// blocks of `R` rows.
pub(super) struct Scalar<const R: usize>;

impl<const R: usize> Lanes for Scalar<R> {
    const R: usize = R;

    #[inline(always)]
    fn dots<const P: usize>(a: &[f32], bt: &[f32], n16: usize, scale: f32, out: &mut [f32]) {
        for j0 in (0..n16).step_by(W) {
            let mut acc = [[0f32; W]; R];
            for d in 0..P {
                let b = &bt[d * n16 + j0..][..W];
                for (r, acc) in acc.iter_mut().enumerate() {
                    let x = a[r * P + d];
                    for l in 0..W {
                        acc[l] += x * b[l];
                    }
                }
            }
            for (r, acc) in acc.iter().enumerate() {
                for l in 0..W {
                    out[r * n16 + j0 + l] = acc[l] * scale;
                }
            }
        }
    }

    #[inline(always)]
    fn mix<const P: usize>(w: &[f32], n16: usize, n: usize, m: &[f32], out: &mut [f32]) {
        out[..R * P].fill(0.0);
        for j in 0..n {
            for r in 0..R {
                let x = w[r * n16 + j];
                for l in 0..P {
                    out[r * P + l] += x * m[j * P + l];
                }
            }
        }
    }

    #[inline(always)]
    fn spread<const P: usize>(w: &[f32], n16: usize, n: usize, x: &[f32], acc: &mut [f32]) {
        for j in 0..n {
            for r in 0..R {
                let c = w[r * n16 + j];
                for l in 0..P {
                    acc[j * P + l] += c * x[r * P + l];
                }
            }
        }
    }
}

/// AVX2 + FMA intrinsics (8 lanes): LLVM does not vectorise the scalar loops' register tiles
/// (it unrolls them into scalar code), so the tiles are written out.
#[cfg(target_arch = "x86_64")]
pub(super) struct Avx2;

/// `Lanes` for an intrinsics build: each product checks its slices' lengths, then calls the
/// build's unsafe tile of module `$m`.
macro_rules! intrinsic_lanes {
    ($ty:ident, $m:ident) => {
        #[cfg(target_arch = "x86_64")]
        impl Lanes for $ty {
            const R: usize = $m::R;

            #[inline(always)]
            fn dots<const P: usize>(
                a: &[f32],
                bt: &[f32],
                n16: usize,
                scale: f32,
                out: &mut [f32],
            ) {
                assert!(
                    a.len() >= Self::R * P && bt.len() >= P * n16 && out.len() >= Self::R * n16
                );
                // SAFETY: the lengths checked above; called only from the build's own head
                // functions, on CPUs with its features.
                unsafe { $m::dots::<P>(a.as_ptr(), bt.as_ptr(), n16, scale, out.as_mut_ptr()) }
            }

            #[inline(always)]
            fn mix<const P: usize>(w: &[f32], n16: usize, n: usize, m: &[f32], out: &mut [f32]) {
                assert!(
                    w.len() >= Self::R * n16
                        && n <= n16
                        && m.len() >= n * P
                        && out.len() >= Self::R * P
                );
                // SAFETY: as above.
                unsafe { $m::mix::<P>(w.as_ptr(), n16, n, m.as_ptr(), out.as_mut_ptr()) }
            }

            #[inline(always)]
            fn spread<const P: usize>(w: &[f32], n16: usize, n: usize, x: &[f32], acc: &mut [f32]) {
                assert!(
                    w.len() >= Self::R * n16
                        && n <= n16
                        && x.len() >= Self::R * P
                        && acc.len() >= n * P
                );
                // SAFETY: as above.
                unsafe { $m::spread::<P>(w.as_ptr(), n16, n, x.as_ptr(), acc.as_mut_ptr()) }
            }
        }
    };
}

intrinsic_lanes!(Avx2, avx2);

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::W;

    /// Rows per block: the scores' tile is 2R of the 16 registers.
    pub(super) const R: usize = 4;
    /// P / 8 registers per row, P <= 32.
    const MAX: usize = 4;

    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn dots<const P: usize>(
        a: *const f32,
        bt: *const f32,
        n16: usize,
        scale: f32,
        out: *mut f32,
    ) {
        let sc = _mm256_set1_ps(scale);
        for j0 in (0..n16).step_by(W) {
            let mut acc = [[_mm256_setzero_ps(); 2]; R];
            for d in 0..P {
                let b0 = _mm256_loadu_ps(bt.add(d * n16 + j0));
                let b1 = _mm256_loadu_ps(bt.add(d * n16 + j0 + 8));
                for (r, acc) in acc.iter_mut().enumerate() {
                    let x = _mm256_broadcast_ss(&*a.add(r * P + d));
                    acc[0] = _mm256_fmadd_ps(x, b0, acc[0]);
                    acc[1] = _mm256_fmadd_ps(x, b1, acc[1]);
                }
            }
            for (r, acc) in acc.iter().enumerate() {
                _mm256_storeu_ps(out.add(r * n16 + j0), _mm256_mul_ps(acc[0], sc));
                _mm256_storeu_ps(out.add(r * n16 + j0 + 8), _mm256_mul_ps(acc[1], sc));
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn mix<const P: usize>(
        w: *const f32,
        n16: usize,
        n: usize,
        m: *const f32,
        out: *mut f32,
    ) {
        let c = P / 8;
        let mut acc = [[_mm256_setzero_ps(); MAX]; R];
        for j in 0..n {
            let mut row = [_mm256_setzero_ps(); MAX];
            for (k, v) in row.iter_mut().enumerate().take(c) {
                *v = _mm256_loadu_ps(m.add(j * P + k * 8));
            }
            for (r, acc) in acc.iter_mut().enumerate() {
                let x = _mm256_broadcast_ss(&*w.add(r * n16 + j));
                for k in 0..c {
                    acc[k] = _mm256_fmadd_ps(x, row[k], acc[k]);
                }
            }
        }
        for (r, acc) in acc.iter().enumerate() {
            for (k, v) in acc.iter().enumerate().take(c) {
                _mm256_storeu_ps(out.add(r * P + k * 8), *v);
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn spread<const P: usize>(
        w: *const f32,
        n16: usize,
        n: usize,
        x: *const f32,
        acc: *mut f32,
    ) {
        let c = P / 8;
        let mut xs = [[_mm256_setzero_ps(); MAX]; R];
        for (r, xr) in xs.iter_mut().enumerate() {
            for (k, v) in xr.iter_mut().enumerate().take(c) {
                *v = _mm256_loadu_ps(x.add(r * P + k * 8));
            }
        }
        for j in 0..n {
            let mut t = [_mm256_setzero_ps(); MAX];
            for (k, v) in t.iter_mut().enumerate().take(c) {
                *v = _mm256_loadu_ps(acc.add(j * P + k * 8));
            }
            for (r, xr) in xs.iter().enumerate() {
                let cr = _mm256_broadcast_ss(&*w.add(r * n16 + j));
                for k in 0..c {
                    t[k] = _mm256_fmadd_ps(cr, xr[k], t[k]);
                }
            }
            for (k, v) in t.iter().enumerate().take(c) {
                _mm256_storeu_ps(acc.add(j * P + k * 8), *v);
            }
        }
    }
}

/// AVX-512 intrinsics (16 lanes), for CPUs that have them: half the instructions of [`Avx2`].
#[cfg(target_arch = "x86_64")]
pub(super) struct Avx512;

intrinsic_lanes!(Avx512, avx512);

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use super::W;

    /// Rows per block: the scores' and the values' tiles are 2R of the 32 registers (8 rows
    /// take 15-20% off the kernel's time against 4, forward and backward, heads of 32).
    pub(super) const R: usize = 8;
    /// P / 16 registers per row, P <= 32.
    const MAX: usize = 2;

    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn dots<const P: usize>(
        a: *const f32,
        bt: *const f32,
        n16: usize,
        scale: f32,
        out: *mut f32,
    ) {
        // Two chunks of keys at a time where there are two: R rows by one chunk are only R
        // chains of dependent FMAs, too few to fill the FMA units. Each score still sums its
        // channels in order, so the bits are those of one chunk at a time.
        let pairs = n16 / (2 * W) * (2 * W);
        for j0 in (0..pairs).step_by(2 * W) {
            chunks::<P, 2>(a, bt, n16, j0, scale, out);
        }
        if pairs < n16 {
            chunks::<P, 1>(a, bt, n16, pairs, scale, out);
        }
    }

    /// `dots` on the C chunks of keys from column j0.
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn chunks<const P: usize, const C: usize>(
        a: *const f32,
        bt: *const f32,
        n16: usize,
        j0: usize,
        scale: f32,
        out: *mut f32,
    ) {
        let mut acc = [[_mm512_setzero_ps(); C]; R];
        for d in 0..P {
            let mut b = [_mm512_setzero_ps(); C];
            for (c, b) in b.iter_mut().enumerate() {
                *b = _mm512_loadu_ps(bt.add(d * n16 + j0 + c * W));
            }
            for (r, acc) in acc.iter_mut().enumerate() {
                let x = _mm512_set1_ps(*a.add(r * P + d));
                for c in 0..C {
                    acc[c] = _mm512_fmadd_ps(x, b[c], acc[c]);
                }
            }
        }
        let sc = _mm512_set1_ps(scale);
        for (r, acc) in acc.iter().enumerate() {
            for (c, acc) in acc.iter().enumerate() {
                _mm512_storeu_ps(out.add(r * n16 + j0 + c * W), _mm512_mul_ps(*acc, sc));
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn mix<const P: usize>(
        w: *const f32,
        n16: usize,
        n: usize,
        m: *const f32,
        out: *mut f32,
    ) {
        let c = P / 16;
        let mut acc = [[_mm512_setzero_ps(); MAX]; R];
        for j in 0..n {
            let mut row = [_mm512_setzero_ps(); MAX];
            for (k, v) in row.iter_mut().enumerate().take(c) {
                *v = _mm512_loadu_ps(m.add(j * P + k * 16));
            }
            for (r, acc) in acc.iter_mut().enumerate() {
                let x = _mm512_set1_ps(*w.add(r * n16 + j));
                for k in 0..c {
                    acc[k] = _mm512_fmadd_ps(x, row[k], acc[k]);
                }
            }
        }
        for (r, acc) in acc.iter().enumerate() {
            for (k, v) in acc.iter().enumerate().take(c) {
                _mm512_storeu_ps(out.add(r * P + k * 16), *v);
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn spread<const P: usize>(
        w: *const f32,
        n16: usize,
        n: usize,
        x: *const f32,
        acc: *mut f32,
    ) {
        let c = P / 16;
        let mut xs = [[_mm512_setzero_ps(); MAX]; R];
        for (r, xr) in xs.iter_mut().enumerate() {
            for (k, v) in xr.iter_mut().enumerate().take(c) {
                *v = _mm512_loadu_ps(x.add(r * P + k * 16));
            }
        }
        for j in 0..n {
            let mut t = [_mm512_setzero_ps(); MAX];
            for (k, v) in t.iter_mut().enumerate().take(c) {
                *v = _mm512_loadu_ps(acc.add(j * P + k * 16));
            }
            for (r, xr) in xs.iter().enumerate() {
                let cr = _mm512_set1_ps(*w.add(r * n16 + j));
                for k in 0..c {
                    t[k] = _mm512_fmadd_ps(cr, xr[k], t[k]);
                }
            }
            for (k, v) in t.iter().enumerate().take(c) {
                _mm512_storeu_ps(acc.add(j * P + k * 16), *v);
            }
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// The tiles of one build compute what the plain loops compute (the kernel test runs
    /// whichever build the CPU picks; this one runs each the CPU has).
    fn check<L: Lanes, const P: usize, const R: usize>(build: &str) {
        assert_eq!(L::R, R);
        let (n, n16) = (37, 48);
        let v = |len: usize, k: usize| -> Vec<f32> {
            (0..len).map(|i| ((i * k) % 97) as f32 / 48.0 - 1.0).collect()
        };
        let (a, bt, w, m) = (v(R * P, 3), v(P * n16, 5), v(R * n16, 7), v(n * P, 11));
        let close = |x: &[f32], y: &[f32]| x.iter().zip(y).all(|(p, q)| (p - q).abs() < 1e-4);
        let (mut o1, mut o2) = (vec![0f32; R * n16], vec![0f32; R * n16]);
        Scalar::<R>::dots::<P>(&a, &bt, n16, 0.25, &mut o1);
        L::dots::<P>(&a, &bt, n16, 0.25, &mut o2);
        assert!(close(&o1, &o2), "{build} dots P={P}");
        let (mut o1, mut o2) = (vec![0f32; R * P], vec![0f32; R * P]);
        Scalar::<R>::mix::<P>(&w, n16, n, &m, &mut o1);
        L::mix::<P>(&w, n16, n, &m, &mut o2);
        assert!(close(&o1, &o2), "{build} mix P={P}");
        let (mut o1, mut o2) = (m.clone(), m.clone());
        Scalar::<R>::spread::<P>(&w, n16, n, &a, &mut o1);
        L::spread::<P>(&w, n16, n, &a, &mut o2);
        assert!(close(&o1, &o2), "{build} spread P={P}");
    }

    #[test]
    fn avx2_tiles_match_the_plain_loops() {
        if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
            eprintln!("notice: no AVX2 + FMA here; the AVX2 tiles are not compared");
            return;
        }
        check::<Avx2, 16, { avx2::R }>("avx2");
        check::<Avx2, 32, { avx2::R }>("avx2");
    }

    #[test]
    fn avx512_tiles_match_the_plain_loops() {
        if !std::is_x86_feature_detected!("avx512f") {
            eprintln!("notice: no AVX-512 here; the AVX-512 tiles are not compared");
            return;
        }
        check::<Avx512, 16, { avx512::R }>("avx512");
        check::<Avx512, 32, { avx512::R }>("avx512");
    }
}
