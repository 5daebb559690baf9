//! Small descriptive statistics shared by the STE, its studies and the reports: median, mean
//! and spread, and the box of a box plot.

/// Median of a slice (NaN-free); NaN for an empty slice.
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// The `q` quantile (`q` in `[0, 1]`) of a NaN-free slice by linear interpolation (the
/// "type 7" rule of R and numpy); NaN for an empty slice.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    sorted_quantile(&s, q)
}

/// [`quantile`] of sorted values.
fn sorted_quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (pos - lo as f64) * (v[hi] - v[lo])
}

/// Mean and sample standard deviation (0 for a single value).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

/// A box: whiskers, quartiles, median, and the values beyond the whiskers.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxStats {
    /// `[low whisker, q1, median, q3, high whisker]`: quartiles by linear interpolation (the
    /// "type 7" rule of R and numpy), whiskers at the furthest values within 1.5 IQR.
    pub five: [f64; 5],
    /// Values beyond the whiskers.
    pub outliers: Vec<f64>,
}

impl BoxStats {
    /// The box of the finite values; `None` when there are none.
    pub fn of(values: &[f64]) -> Option<Self> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let q = |q: f64| sorted_quantile(&v, q);
        let (q1, median, q3) = (q(0.25), q(0.5), q(0.75));
        let reach = 1.5 * (q3 - q1);
        let low = *v.iter().find(|&&x| x >= q1 - reach)?;
        let high = *v.iter().rev().find(|&&x| x <= q3 + reach)?;
        let outliers = v.iter().copied().filter(|&x| x < low || x > high).collect();
        Some(Self {
            five: [low, q1, median, q3, high],
            outliers,
        })
    }
}

/// Mean of the paired differences `other - base` and its standard error (the differences'
/// sample standard deviation over `sqrt n`; 0 for a single pair). The slices must be equally
/// long and not empty.
pub fn paired_difference(base: &[f64], other: &[f64]) -> (f64, f64) {
    assert_eq!(base.len(), other.len(), "paired samples differ in length");
    let d: Vec<f64> = base.iter().zip(other).map(|(a, b)| b - a).collect();
    let (mean, std) = mean_std(&d);
    (mean, std / (d.len() as f64).sqrt())
}

/// Two-sided exact sign test: the chance, when each of `n` trials falls either way with
/// probability 1/2, of a split at least as uneven as `k` against `n - k` (1 for `n = 0`).
pub fn sign_test(k: usize, n: usize) -> f64 {
    assert!(k <= n, "{k} successes of {n} trials");
    let tail = k.min(n - k);
    // ln C(n, i) - n ln 2, term by term.
    let mut ln_term = -(n as f64) * std::f64::consts::LN_2;
    let mut sum = 0.0;
    for i in 0..=tail {
        sum += ln_term.exp();
        ln_term += ((n - i) as f64).ln() - ((i + 1) as f64).ln();
    }
    // An even split's middle term is counted on both sides; the whole cannot exceed 1.
    (2.0 * sum).min(1.0)
}
