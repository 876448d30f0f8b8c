//! The order of the Forstner candidates and the greedy selection with a minimum distance
//! (H04 sec. 2): heap sorts on the rank (interest, then row, then column), bounded loops, no
//! recursion.

use super::Candidate;

/// `a` ranks before `b` (higher interest first, then row, then column).
pub(super) fn ranks_before(a: &Candidate, b: &Candidate) -> bool {
    if a.interest != b.interest {
        return a.interest > b.interest;
    }
    (a.y, a.x) < (b.y, b.x)
}

/// Moves element `root` down the heap of the first `end` elements (min-heap on the rank, so the
/// final order is best first).
pub(super) fn sift_down(list: &mut [Candidate], root: usize, end: usize) {
    sift_down_by(list, root, end, ranks_before);
}

/// Moves element `root` down the best-first heap of the first `end` elements (max-heap on the
/// rank: the child that ranks earlier goes up).
pub(super) fn sift_down_best(list: &mut [Candidate], root: usize, end: usize) {
    sift_down_by(list, root, end, |a, b| ranks_before(b, a));
}

/// The sift-down of both heaps: the right child is taken when `before(left, right)`, and the
/// element stops when `before(child, element)` (`ranks_before` for the min-heap on the rank,
/// its converse for the max-heap).
#[inline(always)]
fn sift_down_by(
    list: &mut [Candidate],
    mut root: usize,
    end: usize,
    before: impl Fn(&Candidate, &Candidate) -> bool,
) {
    for _ in 0..usize::BITS {
        let left = 2 * root + 1;
        if left >= end {
            return;
        }
        let right = left + 1;
        let mut child = left;
        if right < end {
            if let (Some(l), Some(r)) = (list.get(left), list.get(right)) {
                if before(l, r) {
                    child = right;
                }
            }
        }
        let (Some(c), Some(p)) = (list.get(child), list.get(root)) else {
            return;
        };
        if before(c, p) {
            return;
        }
        list.swap(root, child);
        root = child;
    }
}

/// In-place heap sort, best ranked first (bounded loops, no recursion).
pub fn heap_sort_descending(list: &mut [Candidate]) {
    let n = list.len();
    for start in (0..n / 2).rev() {
        sift_down(list, start, n);
    }
    for end in (1..n).rev() {
        list.swap(0, end);
        sift_down(list, 0, end);
    }
}

/// Greedy selection continued over another chunk of the sorted candidates: `out[..count]`
/// holds the features kept so far; returns the new count (see [`select_with_min_distance`]).
pub fn select_more(
    candidates: &[Candidate],
    min_distance_px: f32,
    out: &mut [(u16, u16)],
    count: usize,
) -> usize {
    let min_d2 = min_distance_px * min_distance_px;
    let mut count = count.min(out.len());
    for c in candidates {
        if count >= out.len() {
            break;
        }
        let far = out.get(..count).unwrap_or(&[]).iter().all(|&(x, y)| {
            let dx = f32::from(x) - f32::from(c.x);
            let dy = f32::from(y) - f32::from(c.y);
            dx * dx + dy * dy >= min_d2
        });
        if far {
            if let Some(slot) = out.get_mut(count) {
                *slot = (c.x, c.y);
                count += 1;
            }
        }
    }
    count
}

/// Greedy selection (H04 sec. 2): walks the sorted candidates and keeps each one at least
/// `min_distance_px` from every feature kept so far, until `out` is full. Returns the count.
pub fn select_with_min_distance(
    candidates: &[Candidate],
    min_distance_px: f32,
    out: &mut [(u16, u16)],
) -> usize {
    select_more(candidates, min_distance_px, out, 0)
}
