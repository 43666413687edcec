//! Small statistics of samples: the median (the mean of the two middle values for an even
//! count) and the median with the extremes. Sorting is by `f64::total_cmp`; an empty sample
//! gives NaN.

/// The median of `v`, which is sorted in place; NaN when empty.
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// `(median, min, max)` of a sample; NaN for an empty one.
pub fn median_min_max(xs: &[f64]) -> (f64, f64, f64) {
    let mut v = xs.to_vec();
    let med = median(&mut v);
    match (v.first(), v.last()) {
        (Some(&lo), Some(&hi)) => (med, lo, hi),
        _ => (f64::NAN, f64::NAN, f64::NAN),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_of_odd_even_and_empty_samples() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median_min_max(&[3.0, 1.0, 2.0, 10.0]), (2.5, 1.0, 10.0));
        assert!(median(&mut []).is_nan());
        let e = median_min_max(&[]);
        assert!(e.0.is_nan() && e.1.is_nan() && e.2.is_nan());
    }
}
