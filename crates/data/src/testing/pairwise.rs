//! All-pairs covers for combination tests: rows of factor levels in which every allowed pair of
//! levels of every two factors appears at least once, far fewer rows than the full product.

use std::collections::BTreeSet;

/// A greedy all-pairs cover of factors with `levels[i]` levels each. `allowed(a, x, b, y)`
/// (a < b) says whether level x of factor a may be combined with level y of factor b: no row
/// holds a pair it refuses, and every pair it allows is covered.
pub fn all_pairs(
    levels: &[usize],
    allowed: impl Fn(usize, usize, usize, usize) -> bool,
) -> Vec<Vec<usize>> {
    let f = levels.len();
    let ok = |j: usize, w: usize, k: usize, v: usize| {
        if j < k {
            allowed(j, w, k, v)
        } else {
            allowed(k, v, j, w)
        }
    };
    let mut open: BTreeSet<(usize, usize, usize, usize)> = (0..f)
        .flat_map(|a| (a + 1..f).map(move |b| (a, b)))
        .flat_map(|(a, b)| {
            (0..levels[a]).flat_map(move |x| (0..levels[b]).map(move |y| (a, x, b, y)))
        })
        .filter(|&(a, x, b, y)| allowed(a, x, b, y))
        .collect();
    let mut rows = Vec::new();
    while let Some(&(a, x, b, y)) = open.iter().next() {
        let mut row: Vec<Option<usize>> = vec![None; f];
        row[a] = Some(x);
        row[b] = Some(y);
        for k in 0..f {
            if row[k].is_some() {
                continue;
            }
            let set: Vec<(usize, usize)> = (0..f).filter_map(|j| row[j].map(|w| (j, w))).collect();
            // Among the levels that fit the row, the one covering the most open pairs.
            let gain = |v: usize| {
                set.iter()
                    .filter(|&&(j, w)| {
                        open.contains(&if j < k { (j, w, k, v) } else { (k, v, j, w) })
                    })
                    .count()
            };
            row[k] = (0..levels[k])
                .filter(|&v| set.iter().all(|&(j, w)| ok(j, w, k, v)))
                .max_by_key(|&v| (gain(v), std::cmp::Reverse(v)));
        }
        let row: Vec<usize> =
            row.into_iter().map(|v| v.expect("a level that fits the row")).collect();
        for a in 0..f {
            for b in a + 1..f {
                open.remove(&(a, row[a], b, row[b]));
            }
        }
        rows.push(row);
    }
    rows
}

/// The pairs (a, x, b, y) that `rows` gets wrong: an allowed pair no row covers, or a refused
/// pair some row holds. Empty for a correct cover.
pub fn wrong_pairs(
    levels: &[usize],
    rows: &[Vec<usize>],
    allowed: impl Fn(usize, usize, usize, usize) -> bool,
) -> Vec<(usize, usize, usize, usize)> {
    let f = levels.len();
    (0..f)
        .flat_map(|a| (a + 1..f).map(move |b| (a, b)))
        .flat_map(|(a, b)| {
            (0..levels[a]).flat_map(move |x| (0..levels[b]).map(move |y| (a, x, b, y)))
        })
        .filter(|&(a, x, b, y)| rows.iter().any(|r| r[a] == x && r[b] == y) != allowed(a, x, b, y))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_allowed_pair_is_covered_and_no_refused_one() {
        let levels = [3, 2, 4, 5, 2, 2, 3];
        // Level 0 of factor 0 never goes with level 4 of factor 3.
        let allowed =
            |a: usize, x: usize, b: usize, y: usize| !(a == 0 && x == 0 && b == 3 && y == 4);
        let rows = all_pairs(&levels, allowed);
        assert_eq!(wrong_pairs(&levels, &rows, allowed), vec![]);
        // A cover without its last row misses a pair.
        assert!(!wrong_pairs(&levels, &rows[..rows.len() - 1], allowed).is_empty());
        // The two largest factors alone need 4 x 5 = 20 rows; the full product is 2880.
        assert!(rows.len() >= 20 && rows.len() <= 28, "{} rows", rows.len());
    }
}
