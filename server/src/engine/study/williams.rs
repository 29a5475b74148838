//! The Williams design (a balanced Latin square), the counterbalanced alternative to random
//! orders: for k compensators, k rows when k is even and 2k when k is odd; over the rows
//! every compensator is in every position equally often and every ordered pair of
//! neighbours occurs equally often (first-order carry-over balanced).

/// The rows of the design for `k` compensators, as indices 0..k into the study's list.
///
/// Even k: the first row is 0, 1, k−1, 2, k−2, …, and row r adds r (mod k) to it; each
/// ordered pair of neighbours occurs exactly once. Odd k: those k rows and then their mirror
/// images (row k + r is row r reversed); each ordered pair occurs exactly twice.
pub fn rows(k: usize) -> Vec<Vec<usize>> {
    if k == 0 {
        return vec![];
    }
    let first: Vec<usize> = (0..k)
        .map(|j| match j {
            0 => 0,
            j if j % 2 == 1 => j.div_ceil(2),
            j => k - j / 2,
        })
        .collect();
    let mut out: Vec<Vec<usize>> = (0..k)
        .map(|r| first.iter().map(|&x| (x + r) % k).collect())
        .collect();
    if k % 2 == 1 {
        let mirrors: Vec<Vec<usize>> = out
            .iter()
            .map(|row| row.iter().rev().copied().collect())
            .collect();
        out.extend(mirrors);
    }
    out
}

/// The rows the subject enrolled `enrol_index`-th runs: (on the machine, at the desk).
/// The machine takes row i mod R and the desk row (i + R/2) mod R (R rows): over every R
/// consecutive subjects each seat runs every row once, so each seat — the unit of analysis —
/// is balanced on its own whichever seat a subject starts at; and the two rows differ (for
/// even k a cyclic shift by k/2, for odd k the mirror image), so a subject's second order is
/// never the first. (Taking row i mod R at the *starting* seat instead cannot balance the
/// seats: with k = 2 and starts alternating on, off, on, … the machine would always run
/// row 0.)
pub fn seat_rows(k: usize, enrol_index: u32) -> (usize, usize) {
    let n = if k % 2 == 0 { k } else { 2 * k };
    let i = enrol_index as usize % n;
    (i, (i + n / 2) % n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn every_design_for_2_to_12_compensators_balances_position_and_carry_over() {
        for k in 2..=12 {
            let rows = rows(k);
            let n = if k % 2 == 0 { k } else { 2 * k };
            assert_eq!(rows.len(), n, "k = {k}");
            let mut position = HashMap::new();
            let mut pairs = HashMap::new();
            for row in &rows {
                let mut sorted = row.clone();
                sorted.sort();
                assert_eq!(sorted, (0..k).collect::<Vec<_>>(), "k = {k}: {row:?}");
                for (p, &c) in row.iter().enumerate() {
                    *position.entry((p, c)).or_insert(0) += 1;
                }
                for w in row.windows(2) {
                    *pairs.entry((w[0], w[1])).or_insert(0) += 1;
                }
            }
            // Brute force over every (position, compensator) and every ordered pair.
            let per_position = n / k;
            let per_pair = n / k;
            for p in 0..k {
                for c in 0..k {
                    assert_eq!(position.get(&(p, c)), Some(&per_position), "k = {k}");
                }
            }
            for a in 0..k {
                for b in (0..k).filter(|&b| b != a) {
                    assert_eq!(pairs.get(&(a, b)), Some(&per_pair), "k = {k}: {a}→{b}");
                }
            }
            assert_eq!(pairs.len(), k * (k - 1), "no compensator follows itself");
        }
    }

    #[test]
    fn the_seats_run_different_rows_and_each_seat_every_row() {
        for k in 2..=8 {
            let rows = rows(k);
            let n = rows.len();
            let mut on = vec![0; n];
            let mut off = vec![0; n];
            for i in 0..(3 * n) as u32 {
                let (a, b) = seat_rows(k, i);
                assert_ne!(rows[a], rows[b], "k = {k}, subject {i}");
                on[a] += 1;
                off[b] += 1;
            }
            assert!(on.iter().chain(&off).all(|&c| c == 3), "k = {k}");
        }
    }
}
