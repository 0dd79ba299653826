//! Order statistics shared by the workspace's reports: the quantile and median of a sample.
//!
//! One definition for the whole workspace: [`quantile`] interpolates linearly between order
//! statistics (numpy's default), so the median of an even count is the mean of the two middle
//! values. [`quantile_nearest_rank`] is the other common definition (a value of the sample, never
//! between two), kept for the bus benchmark's latency percentiles.

/// The `q` quantile (0..=1) with linear interpolation between order statistics (numpy's default),
/// so the median of an even count is the mean of the two middle values. NaN for no values.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let pos = q.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// The median ([`quantile`] 0.5): the middle value, or the mean of the two middle values of an
/// even count. NaN for no values.
pub fn median(values: &[f64]) -> f64 {
    quantile(values, 0.5)
}

/// The `q` quantile (0..=1) by nearest rank: the smallest value with at least `q` of the sample at
/// or below it (always a value of the sample). NaN for no values.
pub fn quantile_nearest_rank(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_like_numpy() {
        assert_eq!(median(&[3.0, 1.0, 2.0, 4.0]), 2.5);
        assert_eq!(median(&[5.0]), 5.0);
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(quantile(&[0.0, 10.0], 0.1), 1.0);
        assert_eq!(quantile(&(0..=10).map(f64::from).collect::<Vec<_>>(), 0.9), 9.0);
        assert!(median(&[]).is_nan());
    }

    #[test]
    fn quantile_nearest_rank_picks_a_sample_value() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile_nearest_rank(&v, 0.5), 50.0);
        assert_eq!(quantile_nearest_rank(&v, 0.99), 99.0);
        assert_eq!(quantile_nearest_rank(&v, 1.0), 100.0);
        assert_eq!(quantile_nearest_rank(&v, 0.0), 1.0);
        assert_eq!(quantile_nearest_rank(&[4.0, 1.0, 3.0, 2.0], 0.5), 2.0);
        assert!(quantile_nearest_rank(&[], 0.5).is_nan());
    }
}
