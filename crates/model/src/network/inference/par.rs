//! Parallel regions over token rows: every thread takes one contiguous block of rows and writes
//! only those rows of the buffers it fills.

use std::ops::Range;

use rayon::prelude::*;

/// A destination written by parallel tasks, each on its own rows: the buffer's start and its
/// row width.
#[derive(Clone, Copy)]
pub(super) struct RowsMut(*mut f32, usize);
// SAFETY: the regions hand each task disjoint rows (`par_rows`).
unsafe impl Send for RowsMut {}
unsafe impl Sync for RowsMut {}

impl RowsMut {
    pub(super) fn of(v: &mut [f32], width: usize) -> RowsMut {
        RowsMut(v.as_mut_ptr(), width)
    }

    /// The view from row `rows` on.
    pub(super) fn offset(self, rows: usize) -> RowsMut {
        RowsMut(self.0.wrapping_add(rows * self.1), self.1)
    }

    /// Rows `r`.
    ///
    /// # Safety
    /// No other task may touch these rows while the slice lives, and they must be in bounds.
    pub(super) unsafe fn get<'a>(self, r: &Range<usize>) -> &'a mut [f32] {
        std::slice::from_raw_parts_mut(self.0.add(r.start * self.1), r.len() * self.1)
    }
}

/// `f` on every thread, each with its own contiguous block of `rows` rows: blocks of equal size
/// to a row, and never a single row where there are more (`gemm` takes a matrix-vector path for
/// one row, which rounds differently from the tensor path's product of them all).
pub(super) fn par_rows(rows: usize, f: impl Fn(Range<usize>) + Sync) {
    let tasks = rayon::current_num_threads().min(rows / 2).max(1);
    (0..tasks).into_par_iter().for_each(|c| f(c * rows / tasks..(c + 1) * rows / tasks));
}

/// Rows `r` of a [rows, width] matrix.
pub(super) fn at<'a>(x: &'a [f32], r: &Range<usize>, width: usize) -> &'a [f32] {
    &x[r.start * width..r.end * width]
}
