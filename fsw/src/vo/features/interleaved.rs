//! The rover CPU's layout of the Forstner operator's column sums ([`Interleaved`]) and its
//! row code: the running sums slid one row per work item, and each grid cell's centres scored
//! by a sequential scan with integer floors and early exits ([`score_full`],
//! [`score_partial`]). The row itself is the macro `interleaved_row!`, written into
//! [`ForstnerDetector::process_row_masked`] on the rover CPU and into the host's check of it.

#[cfg(doc)]
use super::ForstnerDetector;
use super::{
    gradient, gradient_rows, Candidate, Thresholds, GRID_PX, SUM_END_COL, SUM_FIRST_COL,
    WINDOW_HALF,
};
use crate::vo::image::Image;
use rover_hal::IMAGE_WIDTH_PX;

/// A compiler-only scheduling barrier (no instruction) on the rover CPU; nothing elsewhere.
#[inline(always)]
fn rover_barrier() {
    #[cfg(target_arch = "arm")]
    core::sync::atomic::compiler_fence(core::sync::atomic::Ordering::SeqCst);
}

/// The column sums of the gradient products, `[xx, yy, xy]` per column, interleaved (the
/// rover CPU's layout, see [`Interleaved`]; kept for the columns
/// [`SUM_FIRST_COL`]`..`[`SUM_END_COL`], the only ones a scored window reaches; the others
/// stay 0).
pub(super) type ColumnSums = [[i32; 3]; IMAGE_WIDTH_PX];

/// Adds the gradient products of image row `y` to the column sums (columns
/// [`SUM_FIRST_COL`]`..`[`SUM_END_COL`]; nothing at the first and last rows).
fn add_row(image: &Image, y: usize, sums: &mut ColumnSums) {
    let Some([up, mid, down]) = gradient_rows(image, y) else {
        return;
    };
    for c in SUM_FIRST_COL..SUM_END_COL {
        let (Some(s), Some(&u), Some(&d), Some(&m0), Some(&m2)) = (
            sums.get_mut(c),
            up.get(c),
            down.get(c),
            mid.get(c - 1),
            mid.get(c + 1),
        ) else {
            break;
        };
        let (gx, gy) = gradient(u, d, i32::from(m0), i32::from(m2));
        s[0] = s[0].wrapping_add(gx * gx);
        s[1] = s[1].wrapping_add(gy * gy);
        s[2] = s[2].wrapping_add(gx * gy);
        // One column at a time (a compiler-only barrier, as in `slide_rows`).
        rover_barrier();
    }
}

/// Adds the gradient products of the window rows `y - WINDOW_HALF..=y + WINDOW_HALF` to the
/// column sums (the first row of a pass): one pass over the columns with the five rows' sums in
/// registers; row by row ([`add_row`]) when a row has no neighbour in the image. Out of line:
/// it runs once per pass and would otherwise change the register use of the per-row code.
#[inline(never)]
pub(super) fn add_window(image: &Image, y: usize, sums: &mut ColumnSums) {
    let row = |k: Option<usize>| {
        k.and_then(|k| image.row(k))
            .and_then(|r| <&[u8; IMAGE_WIDTH_PX]>::try_from(r).ok())
    };
    let first = y.checked_sub(WINDOW_HALF + 1);
    let at = |d: usize| row(first.map(|f| f + d));
    let (Some(r0), Some(r1), Some(r2), Some(r3), Some(r4), Some(r5), Some(r6)) =
        (at(0), at(1), at(2), at(3), at(4), at(5), at(6))
    else {
        for r in y.saturating_sub(WINDOW_HALF)..=y + WINDOW_HALF {
            add_row(image, r, sums);
        }
        return;
    };
    let rows = [r0, r1, r2, r3, r4, r5, r6];
    for c in SUM_FIRST_COL..SUM_END_COL {
        let Some(s) = sums.get_mut(c) else {
            break;
        };
        let mut acc = *s;
        for j in 0..2 * WINDOW_HALF + 1 {
            let (Some(up), Some(mid), Some(down)) = (rows.get(j), rows.get(j + 1), rows.get(j + 2))
            else {
                break;
            };
            let (Some(&u), Some(&d), Some(&m0), Some(&m2)) =
                (up.get(c), down.get(c), mid.get(c - 1), mid.get(c + 1))
            else {
                break;
            };
            let (gx, gy) = gradient(u, d, i32::from(m0), i32::from(m2));
            acc[0] = acc[0].wrapping_add(gx * gx);
            acc[1] = acc[1].wrapping_add(gy * gy);
            acc[2] = acc[2].wrapping_add(gx * gy);
        }
        *s = acc;
        rover_barrier();
    }
}

/// Moves the window down one row: adds the products of row `add`, removes those of row
/// `remove` (one pass over the sums).
#[inline(never)]
pub(super) fn slide_rows(image: &Image, add: usize, remove: usize, sums: &mut ColumnSums) {
    let (Some([au, am, ad]), Some([ru, rm, rd])) =
        (gradient_rows(image, add), gradient_rows(image, remove))
    else {
        return;
    };
    for c in SUM_FIRST_COL..SUM_END_COL {
        let (Some(s), Some(&ru), Some(&rd), Some(&rl), Some(&rr)) = (
            sums.get_mut(c),
            ru.get(c),
            rd.get(c),
            rm.get(c - 1),
            rm.get(c + 1),
        ) else {
            break;
        };
        // The leaving row, then (compiler fences: no instruction) the entering row, and the
        // next column only after this one's stores: few values live at a time, no spills.
        let (rx, ry) = gradient(ru, rd, i32::from(rl), i32::from(rr));
        let [s0, s1, s2] = *s;
        let (s0, s1, s2) = (
            s0.wrapping_sub(rx * rx),
            s1.wrapping_sub(ry * ry),
            s2.wrapping_sub(rx * ry),
        );
        rover_barrier();
        let (Some(&au), Some(&ad), Some(&al), Some(&ar)) =
            (au.get(c), ad.get(c), am.get(c - 1), am.get(c + 1))
        else {
            break;
        };
        let (ax, ay) = gradient(au, ad, i32::from(al), i32::from(ar));
        *s = [
            s0.wrapping_add(ax * ax),
            s1.wrapping_add(ay * ay),
            s2.wrapping_add(ax * ay),
        ];
        rover_barrier();
    }
}

/// Columns of a full cell's span: its [`GRID_PX`] centres and [`WINDOW_HALF`] on each side.
pub(super) const SPAN: usize = GRID_PX + 2 * WINDOW_HALF;

/// Integer lower bounds a pixel must exceed to pass the thresholds and beat a cell's best
/// interest `best` (all conservative: a pixel failing one of them fails the exact tests).
#[derive(Clone, Copy)]
struct Floors {
    /// `floor(4 best)`, or `floor(4 min_interest) - 1` if larger: a pixel needs
    /// `trace > min_trace`, since `w = det / trace <= trace / 4` (det <= (trace / 2)^2 for a
    /// 2x2 normal matrix) and `w > best`, `w >= min_interest`. At least 0.
    min_trace: i32,
    /// `floor(best)`, or `floor(min_interest) - 1` if larger: a pixel needs
    /// `det > w_floor trace` and `min(nxx, nyy) > w_floor` (`w <= nxx nyy / (nxx + nyy) <=
    /// min(nxx, nyy)`).
    w_floor: i32,
}

impl Thresholds {
    /// The floors of a cell whose best interest is `best` (non-negative).
    #[inline(always)]
    fn floors(&self, best: f32) -> Floors {
        let w = f64::from(best);
        Floors {
            min_trace: ((4.0 * w) as i32).max(self.trace_floor),
            w_floor: (w as i32).max(self.w_floor),
        }
    }
}

/// The exact tests of one pixel that passed the trace and diagonal bounds: `(nxx, nyy, nxy)`
/// are its window sums, `trace = nxx + nyy > 0`. Returns the pixel's interest when it passes
/// the interest and roundness thresholds and beats `best`.
#[inline(always)]
fn score_pixel(
    (nxx, nyy, nxy): (i32, i32, i32),
    trace: i32,
    best: f32,
    w_floor: i32,
    t: &Thresholds,
) -> Option<f32> {
    // det exactly in i64 (|products| < 2^42). Integer pre-test of the interest: w_floor <= best
    // and w_floor < min_interest, so det <= w_floor trace fails an f64 test below as well.
    let det = i64::from(nxx) * i64::from(nyy) - i64::from(nxy) * i64::from(nxy);
    if det <= i64::from(w_floor) * i64::from(trace) {
        return None;
    }
    // The definition's tests, in f64 (exact: det and trace below 2^53).
    let (fxx, fyy, fxy) = (f64::from(nxx), f64::from(nyy), f64::from(nxy));
    let det_f = fxx * fyy - fxy * fxy;
    let trace_f = f64::from(trace);
    if det_f > 0.0
        && det_f > f64::from(best) * trace_f
        && !(det_f < t.min_interest * trace_f)
        && !(4.0 * det_f < t.min_roundness * trace_f * trace_f)
    {
        let interest = (det_f / trace_f) as f32;
        if interest > best {
            return Some(interest);
        }
    }
    None
}

/// Scores the window centres of one grid cell in one row: `span` holds the column sums of the
/// columns `first - WINDOW_HALF .. first + n + WINDOW_HALF` for the `n` centres
/// `first..first + n` (`n = span.len() - 2 WINDOW_HALF`, at most [`GRID_PX`]); keeps the
/// best pixel passing the thresholds in `cell` (the first one in scan order on equal
/// interests, as a sequential scan with a strict `>`).
///
/// Window sums in i32: a gradient product is at most 255^2, a column sum five of them, a
/// window sum 25 (< 1.7e6, no overflow on any image). Their products are below 2^53, so det
/// and trace are exact in f64 (and in i64).
#[inline(always)]
fn score_span(span: &[[i32; 3]], first: usize, y: usize, cell: &mut Candidate, t: &Thresholds) {
    const W: usize = 2 * WINDOW_HALF;
    let (mut nxx, mut nyy, mut nxy) = (0i32, 0i32, 0i32);
    for &[a, b, c] in span.iter().take(W) {
        nxx = nxx.wrapping_add(a);
        nyy = nyy.wrapping_add(b);
        nxy = nxy.wrapping_add(c);
    }
    let mut best = cell.interest;
    let mut best_k = None;
    let mut floors = t.floors(best);
    for k in 0..GRID_PX {
        let Some(&[a, b, c]) = span.get(k + W) else {
            break;
        };
        // Window over the columns centre-2..=centre+2.
        nxx = nxx.wrapping_add(a);
        nyy = nyy.wrapping_add(b);
        nxy = nxy.wrapping_add(c);
        let trace = nxx.wrapping_add(nyy);
        // min_trace >= 0, so this also gives trace > 0.
        if trace > floors.min_trace && nxx > floors.w_floor && nyy > floors.w_floor {
            if let Some(interest) = score_pixel((nxx, nyy, nxy), trace, best, floors.w_floor, t) {
                best = interest;
                best_k = Some(k);
                floors = t.floors(interest);
            }
        }
        // Keeps the leaving column's loads after the tests (a compiler-only barrier, no
        // instruction): loaded before them, they stay live across the rare path and spill.
        rover_barrier();
        let Some(&[oa, ob, oc]) = span.get(k) else {
            break;
        };
        nxx = nxx.wrapping_sub(oa);
        nyy = nyy.wrapping_sub(ob);
        nxy = nxy.wrapping_sub(oc);
    }
    if let Some(k) = best_k {
        *cell = Candidate {
            interest: best,
            x: (first + k) as u16,
            y: y as u16,
        };
    }
}

/// [`score_span`] of a full cell ([`GRID_PX`] centres, the span of [`SPAN`] columns),
/// unrolled: no loop counter, every column at a fixed offset.
#[inline(always)]
pub(super) fn score_full(
    span: &[[i32; 3]; SPAN],
    first: usize,
    y: usize,
    cell: &mut Candidate,
    t: &Thresholds,
) {
    let [s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10, s11, s12, s13] = span;
    // The leaving columns read through an opaque copy of the reference: the optimiser would
    // otherwise keep each column in registers from its entering to its leaving (4 columns,
    // 12 values) and spill them; loading it again is one instruction.
    let [_, _, _, _, o4, o5, o6, o7, o8, o9, ..] = core::hint::black_box(span);
    let mut n = [0i32; 3];
    for col in [s0, s1, s2, s3] {
        for (n, &v) in n.iter_mut().zip(col) {
            *n = n.wrapping_add(v);
        }
    }
    let [mut nxx, mut nyy, mut nxy] = n;
    let mut best = cell.interest;
    let mut best_k = None;
    let mut floors = t.floors(best);
    // Centre k: the window over the columns k..=k+4 of the span (entering column `new`,
    // leaving column `old`), tests as in `score_span`.
    macro_rules! centre {
        ($k:expr, $new:ident, $old:ident) => {
            let [a, b, c] = *$new;
            nxx = nxx.wrapping_add(a);
            nyy = nyy.wrapping_add(b);
            nxy = nxy.wrapping_add(c);
            let trace = nxx.wrapping_add(nyy);
            if trace > floors.min_trace && nxx > floors.w_floor && nyy > floors.w_floor {
                if let Some(interest) = score_pixel((nxx, nyy, nxy), trace, best, floors.w_floor, t)
                {
                    best = interest;
                    best_k = Some($k);
                    floors = t.floors(interest);
                }
            }
            rover_barrier();
            let [oa, ob, oc] = *$old;
            nxx = nxx.wrapping_sub(oa);
            nyy = nyy.wrapping_sub(ob);
            nxy = nxy.wrapping_sub(oc);
        };
    }
    centre!(0usize, s4, s0);
    centre!(1, s5, s1);
    centre!(2, s6, s2);
    centre!(3, s7, s3);
    centre!(4, s8, o4);
    centre!(5, s9, o5);
    centre!(6, s10, o6);
    centre!(7, s11, o7);
    centre!(8, s12, o8);
    centre!(9, s13, o9);
    // The last update of the sums is not read.
    let _ = (nxx, nyy, nxy, floors);
    if let Some(k) = best_k {
        *cell = Candidate {
            interest: best,
            x: (first + k) as u16,
            y: y as u16,
        };
    }
}

/// [`score_span`] of a partial cell (fewer than [`GRID_PX`] centres: the loop stops at the
/// end of `span`).
#[inline(never)]
pub(super) fn score_partial(
    span: &[[i32; 3]],
    first: usize,
    y: usize,
    cell: &mut Candidate,
    t: &Thresholds,
) {
    score_span(span, first, y, cell, t);
}

/// The rover CPU's layout of the column sums: `[xx, yy, xy]` together per column
/// ([`ColumnSums`]). On the Cortex-M7 one base pointer walks all three sums (post-indexed loads
/// and stores) and the per-pixel tests run as a sequential scan with early exits
/// ([`score_full`]); the host's [`Planar`] layout gives the same sums and cells bit for bit
/// (integer sums, the same exact tests in the same order; `vo_1_optimised_operator_equals_the_reference`
/// runs both on the host).
#[derive(Debug, Clone)]
pub(super) struct Interleaved(pub(super) ColumnSums);

impl Interleaved {
    /// Zero sums.
    pub(super) const ZERO: Self = Self([[0; 3]; IMAGE_WIDTH_PX]);

    /// Sets every sum to 0.
    #[cfg(target_arch = "arm")]
    pub(super) fn clear(&mut self) {
        self.0.fill([0; 3]);
    }
}

/// The rover CPU's row of [`ForstnerDetector::process_row_masked`] on `$op` (a detector whose
/// `columns` are [`Interleaved`]): one macro so that the flight code and the host's check of
/// it (`vo_1_optimised_operator_equals_the_reference`) are the same source. Written in the
/// method itself: routed through a generic function, the rover CPU build spends 1.6 % more
/// instructions per row.
macro_rules! interleaved_row {
    ($op:ident, $image:ident, $y:ident, $config:ident, $skip_cells:ident) => {{
        let (image, y, config, skip_cells) = ($image, $y, $config, $skip_cells);
        let cell_row = y / GRID_PX;
        let cells = $op
            .cells
            .get_mut(cell_row * GRID_COLS..(cell_row + 1) * GRID_COLS)
            .unwrap_or(&mut []);
        if y == FIRST_ROW || y % GRID_PX == 0 {
            // A grid row's cells are cleared at its first row (the pass reaches every grid
            // row, so all cells are cleared by its end, as by `reset` at its start, without a
            // 37 KB clear in the first item).
            cells.fill(NO_CANDIDATE);
        }
        if y == FIRST_ROW {
            $op.columns.0.fill([0; 3]);
            $op.candidate_count = 0;
            add_window(image, FIRST_ROW, &mut $op.columns.0);
        } else {
            slide_rows(
                image,
                y + WINDOW_HALF,
                y - WINDOW_HALF - 1,
                &mut $op.columns.0,
            );
        }
        let thresholds = Thresholds::new(config);
        // Scored centres: BORDER_PX..IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF (the window of the
        // last one ends inside the border), cell by cell. The skip mask is shifted one cell
        // per step (bit 0 is the current cell).
        let end = IMAGE_WIDTH_PX - BORDER_PX - WINDOW_HALF;
        let mut skip = skip_cells;
        for (c, cell) in cells.iter_mut().enumerate() {
            let skipped = skip & 1 != 0;
            skip >>= 1;
            if skipped {
                continue;
            }
            let first = c * GRID_PX;
            if let Some(span) = $op
                .columns
                .0
                .get(first.wrapping_sub(WINDOW_HALF)..first + GRID_PX + WINDOW_HALF)
                .and_then(|s| <&[[i32; 3]; SPAN]>::try_from(s).ok())
                .filter(|_| first >= BORDER_PX && first + GRID_PX <= end)
            {
                // A full cell: fixed offsets, no checks.
                score_full(span, first, y, cell, &thresholds);
            } else {
                // The partial cells at the borders stop at the end of their shorter span.
                let first = first.max(BORDER_PX);
                let stop = (c * GRID_PX + GRID_PX).min(end);
                if first >= stop {
                    continue;
                }
                if let Some(span) = $op.columns.0.get(first - WINDOW_HALF..stop + WINDOW_HALF) {
                    score_partial(span, first, y, cell, &thresholds);
                }
            }
        }
    }};
}
