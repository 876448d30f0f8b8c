//! The host's layout of the Forstner operator's column sums ([`Planar`]): one array per
//! product, so the compiler vectorises the slide, the window sums and a pre-test of every
//! centre; the same sums and cells, bit for bit, as the rover CPU's [`super::interleaved`]
//! code.

use super::{
    gradient, gradient_rows, Candidate, Row, Thresholds, BORDER_PX, GRID_PX, SUM_END_COL,
    SUM_FIRST_COL, WINDOW_HALF,
};
use crate::vo::image::Image;
use rover_hal::IMAGE_WIDTH_PX;

/// The host's layout of the column sums: one array per product (`[xx, yy, xy]` planes of
/// [`IMAGE_WIDTH_PX`] columns) and the window sums of the current row, so the compiler
/// vectorises the slide, the window sums and a pre-test of every centre; each cell then scans
/// only the centres that pass it. Kept off the rover CPU: a planar slide cost it 16 % more
/// (docs/vo.md), and the f64 pre-test of every centre would run scalar there, where the
/// integer floors of [`score_full`] reject most centres in a few instructions.
#[derive(Debug, Clone)]
pub(super) struct Planar {
    /// Column sums `[xx, yy, xy]` of the window rows, per column.
    sums: [[i32; IMAGE_WIDTH_PX]; 3],
    /// Window (5x5) sums `[xx, yy, xy]` of the current row, per centre column.
    window: [[i32; IMAGE_WIDTH_PX]; 3],
    /// Entry floor of each centre column's cell (interest units, grey levels^2).
    floor: [f32; IMAGE_WIDTH_PX],
    /// 1 where a centre may beat its cell's best (the row's vectorised pre-test).
    pass: [u8; IMAGE_WIDTH_PX],
}

// The planar scan packs a cell's flags into one 8-byte and one 2-byte word.
const _: () = assert!(GRID_PX == 10);

/// One past the last centre the operator scores in a row (its window ends inside the border).
const CENTRE_END: usize = IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF;

/// `(det, trace)` of the normal matrix with the window sums `(nxx, nyy, nxy)`, in f64 (exact:
/// see [`score_span`]).
#[inline(always)]
pub(super) fn det_trace(nxx: i32, nyy: i32, nxy: i32) -> (f64, f64) {
    let (fxx, fyy, fxy) = (f64::from(nxx), f64::from(nyy), f64::from(nxy));
    (fxx * fyy - fxy * fxy, fxx + fyy)
}

/// The image columns [`SUM_FIRST_COL`]`..`[`SUM_END_COL`] of a row shifted by `shift` - 1
/// (0: one column left, 1: in place, 2: one column right).
#[inline(always)]
fn sum_columns<'a>(row: Row<'a>, shift: usize) -> &'a [u8] {
    row.get(SUM_FIRST_COL + shift - 1..SUM_END_COL + shift - 1)
        .unwrap_or(&[])
}

/// The planes' columns [`SUM_FIRST_COL`]`..`[`SUM_END_COL`] (`None` only if these constant
/// ranges left the arrays, which they do not).
#[inline(always)]
fn sum_planes(
    sums: &mut [[i32; IMAGE_WIDTH_PX]; 3],
) -> Option<(&mut [i32], &mut [i32], &mut [i32])> {
    let [xx, yy, xy] = sums;
    Some((
        xx.get_mut(SUM_FIRST_COL..SUM_END_COL)?,
        yy.get_mut(SUM_FIRST_COL..SUM_END_COL)?,
        xy.get_mut(SUM_FIRST_COL..SUM_END_COL)?,
    ))
}

/// The pixels `((up, down), (left, right))` of the central differences of the columns
/// [`SUM_FIRST_COL`]`..`[`SUM_END_COL`] of a row whose neighbours are `[up, mid, down]`.
#[inline(always)]
fn difference_pixels<'a>(
    [up, mid, down]: [Row<'a>; 3],
) -> impl Iterator<Item = ((&'a u8, &'a u8), (&'a u8, &'a u8))> {
    sum_columns(up, 1)
        .iter()
        .zip(sum_columns(down, 1))
        .zip(sum_columns(mid, 0).iter().zip(sum_columns(mid, 2)))
}

/// `sums += products of image row y` over the planes' columns
/// [`SUM_FIRST_COL`]`..`[`SUM_END_COL`] (the first rows of a pass).
fn planar_add_row(sums: &mut [[i32; IMAGE_WIDTH_PX]; 3], rows: [Row; 3]) {
    let Some((xx, yy, xy)) = sum_planes(sums) else {
        return;
    };
    let planes = xx.iter_mut().zip(yy.iter_mut()).zip(xy.iter_mut());
    for (((sxx, syy), sxy), ((&u, &d), (&l, &r))) in planes.zip(difference_pixels(rows)) {
        let (gx, gy) = gradient(u, d, i32::from(l), i32::from(r));
        *sxx = sxx.wrapping_add(gx * gx);
        *syy = syy.wrapping_add(gy * gy);
        *sxy = sxy.wrapping_add(gx * gy);
    }
}

/// The host's f32 pre-test of a centre with the window sums `(nxx, nyy, nxy)` against its
/// cell's entry `floor` (see [`Planar::score_row`]): true whenever the exact tests of
/// [`score_pixel`] pass for a best interest at most `floor` and a `min_interest` at most
/// `floor`, with the roundness threshold `min_roundness`.
#[inline(always)]
pub(super) fn pretest((nxx, nyy, nxy): (i32, i32, i32), floor: f32, min_roundness: f32) -> bool {
    /// 2^-21: eight units in the last place of f32.
    const MARGIN: f32 = 1.0 / (1u32 << 21) as f32;
    let (a, b, x) = (nxx as f32, nyy as f32, nxy as f32);
    let (ab, xx, trace) = (a * b, x * x, a + b);
    let (bound, round) = (floor * trace, min_roundness * trace * trace);
    let (det, spread) = (ab - xx, ab + xx);
    let det_w = det + (spread + bound) * MARGIN;
    let det_q = det + (spread + round.abs()) * MARGIN;
    !(det_w < bound) & !(4.0 * det_q < round)
}

impl Planar {
    /// Zero sums.
    pub(super) const ZERO: Self = Self {
        sums: [[0; IMAGE_WIDTH_PX]; 3],
        window: [[0; IMAGE_WIDTH_PX]; 3],
        floor: [f32::INFINITY; IMAGE_WIDTH_PX],
        pass: [0; IMAGE_WIDTH_PX],
    };

    /// Sets every sum to 0 (and the scratch rows to their initial values: a cleared detector
    /// is [`ForstnerDetector::EMPTY`]).
    pub(super) fn clear(&mut self) {
        *self = Self::ZERO;
    }

    /// Adds the products of the window rows around `y` (the first row of a pass).
    pub(super) fn add_window(&mut self, image: &Image, y: usize) {
        for r in y.saturating_sub(WINDOW_HALF)..=y + WINDOW_HALF {
            if let Some(rows) = gradient_rows(image, r) {
                planar_add_row(&mut self.sums, rows);
            }
        }
    }

    /// Moves the window down one row (adds the products of row `add`, removes row `remove`).
    pub(super) fn slide_rows(&mut self, image: &Image, add: usize, remove: usize) {
        let (Some(added), Some(removed), Some((xx, yy, xy))) = (
            gradient_rows(image, add),
            gradient_rows(image, remove),
            sum_planes(&mut self.sums),
        ) else {
            return;
        };
        let planes = xx.iter_mut().zip(yy.iter_mut()).zip(xy.iter_mut());
        let rows = difference_pixels(added).zip(difference_pixels(removed));
        for (((sxx, syy), sxy), (((&au, &ad), (&al, &ar)), ((&ru, &rd), (&rl, &rr)))) in
            planes.zip(rows)
        {
            let (ax, ay) = gradient(au, ad, i32::from(al), i32::from(ar));
            let (rx, ry) = gradient(ru, rd, i32::from(rl), i32::from(rr));
            // a^2 - r^2 = (a - r)(a + r): the same integer, one product fewer.
            *sxx = sxx.wrapping_add((ax - rx) * (ax + rx));
            *syy = syy.wrapping_add((ay - ry) * (ay + ry));
            *sxy = sxy.wrapping_add((ax * ay).wrapping_sub(rx * ry));
        }
    }

    /// Scores the centres of image row `y` into its grid row's `cells`, skipping the cells
    /// whose bit is set in `skip_cells` (bit `c` for grid column `c`): the same cells, bit for
    /// bit, as the rover CPU's sequential scan ([`super::interleaved`]'s `score_full` and
    /// `score_partial`). The window sums of the row, each centre's entry floor, the pre-test of
    /// every centre, then the exact scan of each cell over its passing centres.
    pub(super) fn score_row(
        &mut self,
        cells: &mut [Candidate],
        y: usize,
        skip_cells: u64,
        t: &Thresholds,
    ) {
        self.window_sums();
        // In f32: `min_interest` is a configured f32 and `best` an f32, so the floor is exact.
        let (min_interest, min_roundness) = (t.min_interest as f32, t.min_roundness as f32);
        self.entry_floors(cells, min_interest);
        if self.pretest_row(min_roundness).is_none() {
            return;
        }
        let [wxx, wyy, wxy] = &self.window;
        let cell_sums = wxx
            .chunks_exact(GRID_PX)
            .zip(wyy.chunks_exact(GRID_PX))
            .zip(wxy.chunks_exact(GRID_PX));
        let mut skip = skip_cells;
        for (c, ((cell, pass), sums)) in cells
            .iter_mut()
            .zip(self.pass.chunks_exact(GRID_PX))
            .zip(cell_sums)
            .enumerate()
        {
            let skipped = skip & 1 != 0;
            skip >>= 1;
            if skipped {
                continue;
            }
            scan_cell(cell, pass, sums, c * GRID_PX, y, t);
        }
    }

    /// The window sums of every centre `BORDER_PX..CENTRE_END` of the row (columns
    /// `centre-2..=centre+2` of the column sums), per product.
    #[inline(always)]
    fn window_sums(&mut self) {
        for (plane, window) in self.sums.iter().zip(self.window.iter_mut()) {
            let (Some(out), Some(s)) = (
                window.get_mut(BORDER_PX..CENTRE_END),
                plane.get(SUM_FIRST_COL..SUM_END_COL),
            ) else {
                continue;
            };
            let s1 = s.get(1..).unwrap_or(&[]);
            let s2 = s.get(2..).unwrap_or(&[]);
            let s3 = s.get(3..).unwrap_or(&[]);
            let s4 = s.get(4..).unwrap_or(&[]);
            for (o, ((((&a, &b), &c), &d), &e)) in
                out.iter_mut().zip(s.iter().zip(s1).zip(s2).zip(s3).zip(s4))
            {
                *o = a
                    .wrapping_add(b)
                    .wrapping_add(c)
                    .wrapping_add(d)
                    .wrapping_add(e);
            }
        }
    }

    /// Each centre's entry floor: its cell's best on entry or the interest threshold
    /// `min_interest`, whichever is higher. Cell c covers the columns c GRID_PX.. of every
    /// per-column array.
    #[inline(always)]
    fn entry_floors(&mut self, cells: &[Candidate], min_interest: f32) {
        for (floor, cell) in self.floor.chunks_exact_mut(GRID_PX).zip(cells.iter()) {
            floor.fill(cell.interest.max(min_interest));
        }
    }

    /// The centres that may beat their cell's best, branch-free over the row (vectorised,
    /// four f32 lanes): the interest and roundness tests of `score_pixel` in f32 with a
    /// margin, `det + m_w >= floor trace` and `4 (det + m_q) >= min_roundness trace^2`,
    /// `m_w = 2^-21 (nxx nyy + nxy^2 + floor trace)`, `m_q = 2^-21 (nxx nyy + nxy^2 +
    /// |min_roundness trace^2|)`, each written as `!(x < y)` so that a NaN threshold passes
    /// as in `score_pixel`. A centre passing the exact tests (det > best trace and
    /// det >= min_interest trace, so det >= floor trace up to 2^-53; the roundness test)
    /// passes these: the window sums and the trace are exact in f32 (below 2^24), the f32
    /// det is within 2.0001 2^-24 (nxx nyy + nxy^2) of the true one, each f32 product
    /// within 2^-23 of its value, and each margin about 8 2^-24 of the sum it bounds. A
    /// centre failing them fails the exact tests for every later, higher best too. Only the
    /// scored centres are written: the others stay 0. `None` only if the constant range of
    /// the scored centres left the arrays, which it does not.
    #[inline(always)]
    fn pretest_row(&mut self, min_roundness: f32) -> Option<()> {
        let [wxx, wyy, wxy] = &self.window;
        let range = BORDER_PX..CENTRE_END;
        let (Some(pass), Some(floor), Some(nxx), Some(nyy), Some(nxy)) = (
            self.pass.get_mut(range.clone()),
            self.floor.get(range.clone()),
            wxx.get(range.clone()),
            wyy.get(range.clone()),
            wxy.get(range),
        ) else {
            return None;
        };
        for ((p, &floor), ((&a, &b), &x)) in
            pass.iter_mut().zip(floor).zip(nxx.iter().zip(nyy).zip(nxy))
        {
            *p = u8::from(pretest((a, b, x), floor, min_roundness));
        }
        Some(())
    }

    /// The sums `[xx, yy, xy]` of column `c` (tests).
    #[cfg(test)]
    pub(super) fn column(&self, c: usize) -> [i32; 3] {
        [self.sums[0][c], self.sums[1][c], self.sums[2][c]]
    }
}

/// The exact scan of one grid cell whose first centre is column `x0` of row `y`: `pass` holds
/// the pre-test's flags of its [`GRID_PX`] centres and `(nxx, nyy, nxy)` their window sums.
/// The sequential scan of `score_span` over the passing centres, in order, with the exact
/// tests of `score_pixel`; keeps the best in `cell`.
#[inline(always)]
fn scan_cell(
    cell: &mut Candidate,
    pass: &[u8],
    ((nxx, nyy), nxy): ((&[i32], &[i32]), &[i32]),
    x0: usize,
    y: usize,
    t: &Thresholds,
) {
    // The cell's flags (0 or 1) as a bit mask, bit k for centre k: most cells have no
    // candidate in a row, two loads tell. Byte i of `lo` moves to bit 56 + i of the
    // product (the other partial products land on distinct lower bits or overflow).
    let lo = pass
        .get(..8)
        .and_then(|b| <[u8; 8]>::try_from(b).ok())
        .map_or(0, u64::from_le_bytes);
    let hi = pass
        .get(8..)
        .and_then(|b| <[u8; GRID_PX - 8]>::try_from(b).ok())
        .map_or(0, u16::from_le_bytes);
    if lo == 0 && hi == 0 {
        return;
    }
    let mut candidates = (lo.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u32
        | u32::from(hi & 1) << 8
        | u32::from(hi >> 8) << 9;
    let mut best = cell.interest;
    let mut best_k = None;
    for _ in 0..GRID_PX {
        if candidates == 0 {
            break;
        }
        let k = candidates.trailing_zeros() as usize;
        candidates &= candidates - 1;
        let (Some(&a), Some(&b), Some(&x)) = (nxx.get(k), nyy.get(k), nxy.get(k)) else {
            break;
        };
        let (det, trace) = det_trace(a, b, x);
        if det > f64::from(best) * trace
            && !(det < t.min_interest * trace)
            && !(4.0 * det < t.min_roundness * trace * trace)
        {
            let interest = (det / trace) as f32;
            if interest > best {
                best = interest;
                best_k = Some(k);
            }
        }
    }
    if let Some(k) = best_k {
        *cell = Candidate {
            interest: best,
            x: (x0 + k) as u16,
            y: y as u16,
        };
    }
}
