//! The line search of the Newton-type solvers, on `phi(alpha) = E(x + alpha d)`.
//!
//! Armijo sufficient decrease, plus a curvature test: a full step that
//! overshoots the minimum along the line (the slope at the trial point turned
//! positive beyond [`CURVATURE`] of the initial one), typical where friction
//! switches between stick and slip, is bracketed and the line minimum located
//! by safeguarded secant steps on the slope; otherwise the step is halved until
//! the energy decreases. Near convergence, where the decrease hides in the
//! round-off, a step at the line minimum (small slope) is accepted.
//!
//! The search only sees `phi` and its slope through a closure, so that any
//! solver can use it: the caller evaluates its energy (and gradient) at
//! `x + alpha d` and keeps that evaluation. The last call of the closure is
//! always at the step length returned, so the caller can take the state of its
//! last evaluation as the new iterate.

/// Armijo sufficient-decrease constant.
pub const ARMIJO: f64 = 1e-4;
/// `|phi'(alpha)| <= CURVATURE |phi'(0)|` accepts a step at the line minimum.
pub const CURVATURE: f64 = 0.5;
/// Secant steps locating an overshot line minimum.
pub const MAX_SECANT: usize = 8;
/// Backtracking halvings before the line search gives up.
pub const MAX_HALVINGS: usize = 40;
/// Energy differences below this many ulps of the energy scale are round-off.
pub const ROUNDOFF_ULPS: f64 = 64.0;
/// Relative energy increase still taken as round-off when the slope shows
/// that the trial point is at the line minimum. The energy sums terms much
/// larger than its changes near convergence (the inertia `d^T M d / h^2` of a
/// basis whose affine and learned modes overlap is computed from coordinates
/// that cancel), so its round-off can reach 1e-9 of its value, while the slope
/// (a gradient, linear in those coordinates) stays accurate.
pub const NOISE: f64 = 1e-8;

/// A step accepted by [`line_search`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineStep {
    /// Step length alpha.
    pub alpha: f64,
    /// `phi(alpha)`, in the units of the energy given.
    pub energy: f64,
}

/// Whether `e` at step length `alpha` decreases `e0` enough along a line of
/// initial slope `d0` (Armijo, with [`ROUNDOFF_ULPS`] of the energy scale
/// allowed for round-off).
pub fn sufficient_decrease(e0: f64, d0: f64, alpha: f64, e: f64) -> bool {
    e.is_finite() && e <= e0 + ARMIJO * alpha * d0 + ROUNDOFF_ULPS * f64::EPSILON * e0.abs().max(e.abs())
}

/// Line search from `phi(0) = e0` with slope `d0 < 0` (see the module
/// documentation). `phi(alpha)` returns the energy and the slope at step
/// length `alpha`. Returns the step taken, or `None` when no step decreases
/// the energy beyond round-off; on success the last call of `phi` was at the
/// step returned.
pub fn line_search(e0: f64, d0: f64, mut phi: impl FnMut(f64) -> (f64, f64)) -> Option<LineStep> {
    let ok = |a: f64, e: f64, d: f64| {
        if sufficient_decrease(e0, d0, a, e) {
            return true;
        }
        // Near convergence the decrease hides in the round-off of E; there a
        // step at the line minimum (small slope) is taken.
        let scale = e0.abs().max(e.abs());
        e.is_finite() && e <= e0 + NOISE * scale && d.is_finite() && d.abs() <= CURVATURE * d0.abs()
    };
    let (e1, d1) = phi(1.0);
    let good1 = ok(1.0, e1, d1);
    if good1 && d1 <= CURVATURE * d0.abs() {
        return Some(LineStep { alpha: 1.0, energy: e1 });
    }
    let mut hi = 1.0;
    if d1.is_finite() && d1 > 0.0 {
        // Overshoot: the line minimum lies in (0, 1); bracket it by secant steps.
        let mut best = good1.then_some(LineStep { alpha: 1.0, energy: e1 });
        let (mut lo, mut dlo, mut dhi) = (0.0, d0, d1);
        let mut last = 1.0;
        for _ in 0..MAX_SECANT {
            let width = hi - lo;
            // A secant through slopes that overflow (or are equal) gives no point: bisect, so that the
            // bracket stays finite.
            let secant = lo - dlo * width / (dhi - dlo);
            let a = if secant.is_finite() { secant.clamp(lo + 0.05 * width, hi - 0.05 * width) } else { lo + 0.5 * width };
            let (e, d) = phi(a);
            last = a;
            let good = ok(a, e, d);
            if good && best.is_none_or(|b| e < b.energy) {
                best = Some(LineStep { alpha: a, energy: e });
            }
            if good && d.abs() <= CURVATURE * d0.abs() {
                return Some(LineStep { alpha: a, energy: e });
            }
            if good && d < 0.0 {
                (lo, dlo) = (a, d);
            } else if d.is_finite() && d > 0.0 {
                (hi, dhi) = (a, d);
            } else {
                break;
            }
        }
        if let Some(b) = best {
            if b.alpha != last {
                phi(b.alpha);
            }
            return Some(b);
        }
    } else if good1 {
        return Some(LineStep { alpha: 1.0, energy: e1 });
    }
    let mut alpha = 0.5 * hi;
    for _ in 0..MAX_HALVINGS {
        let (e, d) = phi(alpha);
        if ok(alpha, e, d) {
            return Some(LineStep { alpha, energy: e });
        }
        alpha *= 0.5;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs the search on `f` along the line from `x0` with step `d`, recording
    /// the step lengths tried.
    fn search(f: impl Fn(f64) -> (f64, f64), x0: f64, d: f64) -> (Option<LineStep>, Vec<f64>) {
        let mut tried = Vec::new();
        let (e0, g0) = f(x0);
        let step = line_search(e0, g0 * d, |a| {
            tried.push(a);
            let (e, g) = f(x0 + a * d);
            (e, g * d)
        });
        (step, tried)
    }

    #[test]
    fn newton_step_on_a_quadratic_is_taken_in_one_trial() {
        // phi = k/2 (x - 2)^2 from x = 0 with the Newton step d = 2.
        let f = |x: f64| (1.5 * (x - 2.0).powi(2), 3.0 * (x - 2.0));
        let (step, tried) = search(f, 0.0, 2.0);
        assert_eq!(step, Some(LineStep { alpha: 1.0, energy: 0.0 }));
        assert_eq!(tried, vec![1.0]);
    }

    #[test]
    fn overshoot_on_a_quadratic_is_bracketed_to_the_minimum() {
        // A step four times too long: the slope at alpha = 1 is positive and
        // the secant on the (linear) slope lands on the minimum at alpha = 1/4.
        let f = |x: f64| (0.5 * (x - 1.0).powi(2), x - 1.0);
        let (step, tried) = search(f, 0.0, 4.0);
        let step = step.expect("a step");
        assert!((step.alpha - 0.25).abs() < 1e-12, "{step:?}");
        assert!(step.energy < 1e-20);
        assert_eq!(*tried.last().unwrap(), step.alpha);
    }

    #[test]
    fn kinked_friction_like_function_stops_in_the_stick_region() {
        // Stick stiffness c up to a slip s, then Coulomb slip (slope capped at
        // mu f_n = c s), minus a driving force f < c s: the minimum lies in the
        // stick region at x = f / c, and a step from the slip side on one side
        // to the slip side on the other overshoots it.
        let (c, s, force) = (500.0, 0.02, 2.0);
        let f = move |x: f64| {
            let (e, g) = if x.abs() <= s { (0.5 * c * x * x, c * x) } else { (c * s * x.abs() - 0.5 * c * s * s, c * s * x.signum()) };
            (e - force * x, g - force)
        };
        let (x0, d) = (-0.1, 0.2);
        let (step, tried) = search(f, x0, d);
        let step = step.expect("a step");
        let x = x0 + step.alpha * d;
        assert!(step.energy < f(x0).0, "{step:?}");
        assert!(tried.len() > 1, "the full step overshoots: {tried:?}");
        assert!(x.abs() <= s, "stopped at {x}, outside the stick region");
        assert!(f(x).1.abs() <= CURVATURE * f(x0).1.abs(), "slope {} at {x}", f(x).1);
        assert_eq!(*tried.last().unwrap(), step.alpha);
    }

    #[test]
    fn an_ascent_direction_gets_no_more_than_round_off() {
        // Halving shrinks the increase until it hides in the round-off allowance.
        let f = |x: f64| (x * x, 2.0 * x);
        let (step, _) = search(f, 1.0, 1.0);
        let step = step.expect("a step within round-off");
        assert!(step.energy - 1.0 <= ROUNDOFF_ULPS * f64::EPSILON, "{step:?}");
    }

    #[test]
    fn non_finite_energies_are_refused_after_a_bounded_number_of_trials() {
        let mut trials = 0;
        let step = line_search(1.0, -1.0, |_| {
            trials += 1;
            (f64::INFINITY, f64::NAN)
        });
        assert_eq!(step, None);
        assert_eq!(trials, 1 + MAX_HALVINGS);
    }

    #[test]
    fn an_increase_within_the_noise_is_accepted_only_at_the_line_minimum() {
        let (e0, d0) = (1e6, -1.0);
        // Above the Armijo allowance (round-off of 1e6 is about 1e-8), within NOISE, zero slope.
        let step = line_search(e0, d0, |_| (e0 * (1.0 + 1e-9), 0.0));
        assert_eq!(step.map(|s| s.alpha), Some(1.0));
        // The same increase with a steep slope, or a larger one, is refused.
        assert_eq!(line_search(e0, d0, |_| (e0 * (1.0 + 1e-9), -0.9)), None);
        assert_eq!(line_search(e0, d0, |_| (e0 * (1.0 + 1e-7), 0.0)), None);
    }

    #[test]
    fn sufficient_decrease_is_armijo() {
        assert!(sufficient_decrease(1.0, -1.0, 1.0, 1.0 - 2.0 * ARMIJO));
        assert!(!sufficient_decrease(1.0, -1.0, 1.0, 1.0 - 0.5 * ARMIJO));
        assert!(sufficient_decrease(1.0, -1.0, 0.5, 1.0 - 0.75 * ARMIJO));
        assert!(!sufficient_decrease(1.0, -1.0, 1.0, f64::NAN));
    }
}
