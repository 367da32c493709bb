//! Friction laws of the two shaft halves (bench-model.md §2, "Friction models").
//!
//! Every law here gives the *non-viscous* friction torque: the linear viscous terms `c1*w1`,
//! `c2*w2` are always part of the mechanics (they are in the linear part that is discretised
//! exactly). A law gives, for a body sliding in direction `s = +-1` at speed `|w|`, the signed
//! torque it applies to the body, and the static capacity (the largest holding torque) in each
//! direction when the body is at rest. Stick/slip switching itself lives in the plant.

use super::{BenchParameters, FrictionModel, hd_loss};

/// Which half of the shaft.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Side {
    /// Actuation side (theta1, after the harmonic drive).
    Actuation,
    /// Load side (theta2).
    Load,
}

/// Coefficients of the exponential (Stribeck-like) law
/// `T = [a0 + a1 exp(-b1|w|) + a2 (1 - exp(-b2|w|))] sign(w)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StribeckLaw {
    pub a0: f64,
    pub a1: f64,
    pub b1: f64,
    pub a2: f64,
    pub b2: f64,
}

impl StribeckLaw {
    /// Magnitude of the friction torque at speed magnitude `speed` [rad/s].
    pub(crate) fn magnitude(&self, speed: f64) -> f64 {
        self.a0 + self.a1 * (-self.b1 * speed).exp() + self.a2 * (1.0 - (-self.b2 * speed).exp())
    }

    /// `d magnitude / d speed` at speed magnitude `speed` [N m s/rad].
    pub(crate) fn slope(&self, speed: f64) -> f64 {
        -self.a1 * self.b1 * (-self.b1 * speed).exp() + self.a2 * self.b2 * (-self.b2 * speed).exp()
    }
}

/// Friction of one side as configured, evaluated at the start of a segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum SideLaw {
    /// No friction element.
    None,
    /// Coulomb friction of the given magnitude [Nm].
    Coulomb(f64),
    /// Exponential law.
    Stribeck(StribeckLaw),
    /// Harmonic-drive loss surface at a frozen load torque [Nm, output side].
    Surface { load_torque: f64 },
}

impl SideLaw {
    /// The law of `side` for the parameters and the current load torque (output side).
    pub(crate) fn of(params: &BenchParameters, side: Side, load_torque: f64) -> Self {
        match (params.friction_model, side) {
            (FrictionModel::Off, _) => SideLaw::None,
            (FrictionModel::CoulombViscous, Side::Actuation) => {
                coulomb(params.actuation_static_friction)
            }
            (FrictionModel::CoulombViscous, Side::Load)
            | (FrictionModel::HdLossSurface, Side::Load) => coulomb(params.load_static_friction),
            (FrictionModel::Exponential, Side::Actuation) => SideLaw::Stribeck(StribeckLaw {
                a0: params.actuation_stribeck_a0,
                a1: params.actuation_stribeck_a1,
                b1: params.actuation_stribeck_b1,
                a2: params.actuation_stribeck_a2,
                b2: params.actuation_stribeck_b2,
            }),
            (FrictionModel::Exponential, Side::Load) => SideLaw::Stribeck(StribeckLaw {
                a0: params.load_stribeck_a0,
                a1: params.load_stribeck_a1,
                b1: params.load_stribeck_b1,
                a2: params.load_stribeck_a2,
                b2: params.load_stribeck_b2,
            }),
            (FrictionModel::HdLossSurface, Side::Actuation) => SideLaw::Surface { load_torque },
        }
    }

    /// Whether the torque depends on the speed (then it is held over a segment with a
    /// predictor-corrector average instead of being exactly constant).
    pub(crate) fn speed_dependent(&self) -> bool {
        matches!(self, SideLaw::Stribeck(_) | SideLaw::Surface { .. })
    }

    /// Signed torque on a body sliding in `direction` (+1/-1) at `speed` >= 0, and whether the
    /// loss surface had to be clamped.
    pub(crate) fn sliding_torque(
        &self,
        params: &BenchParameters,
        direction: f64,
        speed: f64,
    ) -> (f64, bool) {
        match *self {
            SideLaw::None => (0.0, false),
            SideLaw::Coulomb(level) => (-direction * level, false),
            SideLaw::Stribeck(law) => (-direction * law.magnitude(speed), false),
            SideLaw::Surface { load_torque } => hd_loss::clamped_torque(
                load_torque,
                speed,
                direction,
                params.hd_surface_max_speed,
                (
                    params.hd_surface_min_load_torque,
                    params.hd_surface_max_load_torque,
                ),
                params.hd_loss_coefficients(direction),
            ),
        }
    }

    /// Time derivative of [`Self::sliding_torque`] while the body keeps sliding in `direction`:
    /// `speed_rate` is `d|w|/dt`, `load_torque_rate` the rate of the load torque the loss
    /// surface reads. Coulomb friction (and none) is constant while sliding: 0; the exponential
    /// law and the loss surface by the chain rule (a surface argument clamped to the tested box
    /// is constant there).
    pub(crate) fn sliding_torque_rate(
        &self,
        params: &BenchParameters,
        direction: f64,
        speed: f64,
        speed_rate: f64,
        load_torque_rate: f64,
    ) -> f64 {
        match *self {
            SideLaw::None | SideLaw::Coulomb(_) => 0.0,
            SideLaw::Stribeck(law) => -direction * law.slope(speed) * speed_rate,
            SideLaw::Surface { load_torque } => hd_loss::clamped_torque_rate(
                load_torque,
                load_torque_rate,
                speed,
                speed_rate,
                direction,
                params.hd_surface_max_speed,
                (
                    params.hd_surface_min_load_torque,
                    params.hd_surface_max_load_torque,
                ),
                params.hd_loss_coefficients(direction),
            ),
        }
    }

    /// Static capacity (largest holding torque, >= 0) against motion in `direction`.
    pub(crate) fn capacity(&self, params: &BenchParameters, direction: f64) -> f64 {
        let (torque, _) = self.sliding_torque(params, direction, 0.0);
        (-direction * torque).max(0.0)
    }
}

fn coulomb(level: f64) -> SideLaw {
    if level > 0.0 {
        SideLaw::Coulomb(level)
    } else {
        SideLaw::None
    }
}

#[cfg(test)]
/// `J(z) = integral_0^{pi/2} exp(-z sin(phi)) sin(phi) dphi`, the first-harmonic weight of an
/// exponential term under sinusoidal motion (midpoint rule, accurate to ~1e-9 for z < 100).
pub(crate) fn first_harmonic_weight(z: f64) -> f64 {
    let n = 4000;
    let step = std::f64::consts::FRAC_PI_2 / n as f64;
    (0..n)
        .map(|k| {
            let phi = (k as f64 + 0.5) * step;
            (-z * phi.sin()).exp() * phi.sin()
        })
        .sum::<f64>()
        * step
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The documented fit: at 0.5 Hz and 30 deg amplitude the exponential law has the same first
    /// harmonic (so dissipates the same energy per cycle) as Coulomb friction Tfr,static, and its
    /// stiction a0 + a1 equals Tfr,static.
    #[test]
    fn stribeck_defaults_reproduce_static_friction_at_half_hertz() {
        let p = BenchParameters::default();
        let peak_speed = 30f64.to_radians() * 2.0 * std::f64::consts::PI * 0.5;
        for (side, static_friction) in [
            (Side::Actuation, p.actuation_static_friction),
            (Side::Load, p.load_static_friction),
        ] {
            let mut q = p.clone();
            q.friction_model = FrictionModel::Exponential;
            let SideLaw::Stribeck(law) = SideLaw::of(&q, side, 0.0) else {
                panic!("exponential law expected")
            };
            assert!((law.a0 + law.a1 - static_friction).abs() < 1e-12);
            let equivalent = law.a0
                + law.a1 * first_harmonic_weight(law.b1 * peak_speed)
                + law.a2 * (1.0 - first_harmonic_weight(law.b2 * peak_speed));
            assert!(
                (equivalent / static_friction - 1.0).abs() < 1e-4,
                "{side:?}: {equivalent} vs {static_friction}"
            );
        }
    }

    #[test]
    fn capacities_and_signs() {
        let p = BenchParameters::default();
        let law = SideLaw::of(&p, Side::Actuation, 0.0);
        assert_eq!(law, SideLaw::Coulomb(5.0));
        assert_eq!(law.sliding_torque(&p, 1.0, 3.0).0, -5.0);
        assert_eq!(law.capacity(&p, -1.0), 5.0);
        let mut q = p.clone();
        q.friction_model = FrictionModel::HdLossSurface;
        let surface = SideLaw::of(&q, Side::Actuation, 0.0);
        assert!((surface.capacity(&q, 1.0) - 3.218).abs() < 1e-12);
        assert!((surface.capacity(&q, -1.0) - 3.307).abs() < 1e-12);
        q.friction_model = FrictionModel::Off;
        assert_eq!(SideLaw::of(&q, Side::Load, 0.0).capacity(&q, 1.0), 0.0);
    }
}
