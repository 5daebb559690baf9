//! Finite-volume face profiles shared by the wind and transport solvers.
//!
//! In Patankar's generalised form a face between cells `P` and `N` with outward flux `F` and
//! diffusive conductance `D` has neighbour coefficient `a_N = D A(|Pe|) + max(-F, 0)`, with the
//! cell Peclet number `Pe = F / D`. The profile `A` is the scheme.

/// Face profile `A(|Pe|)` of a finite-volume scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Scheme {
    /// Central differencing (`A = 1 - |Pe|/2`) where `|Pe| <= 2`, the exponential profile above
    /// (where central would give negative coefficients). Second order in smooth regions.
    #[default]
    Central,
    /// First-order upwind (`A = 1`): robust and diffusive.
    Upwind,
    /// Patankar's power law (`A = max(0, (1 - |Pe|/10)^5)`): a cheap, smooth fit of the
    /// exponential profile.
    PowerLaw,
    /// Patankar's exponential scheme (`A = |Pe| / (exp|Pe| - 1)`): exact for 1D steady
    /// advection-diffusion, smooth in `Pe`, and `1 - |Pe|/2 + Pe^2/12 + ...` near zero.
    Exponential,
}

impl Scheme {
    /// `A(|pe|)` for a face Peclet (or Reynolds) number `pe`.
    pub fn profile(self, pe: f64) -> f64 {
        let pe = pe.abs();
        match self {
            Scheme::Central if pe <= 2.0 => 1.0 - 0.5 * pe,
            Scheme::Upwind => 1.0,
            Scheme::PowerLaw => (1.0 - 0.1 * pe).max(0.0).powi(5),
            Scheme::Central | Scheme::Exponential => {
                if pe < 1e-6 {
                    1.0 - 0.5 * pe
                } else {
                    pe / pe.exp_m1()
                }
            }
        }
    }
}
