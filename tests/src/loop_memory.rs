//! How long a closed loop remembers a host's stall: the decay rate of the slowest mode of a PID
//! loop around a mass ([`slowest_decay`]), the study's SEA loops' rates ([`sea_loop_decays`]),
//! and a run's stalls carried on at such a rate ([`carried`]). A stall of the real-time loop
//! displaces a sample (or holds a command) once, and the controllers act on it until the loop
//! has rejected it: the real-time tests that compare a bench run with its simulated twin
//! (tests/hardware.rs) and those that decide whether a trip was the host's (tests/hardware.rs,
//! tests/study_bench.rs) read a stall's effect over the rows after it, not on its own row only.

/// The decay rate \[1/s\] of the slowest mode a displaced sample excites in a PID loop around
/// a mass `[inertia, damping, stiffness]`, the controller's output (amperes) reaching the mass
/// through `loop_gain` (torque per ampere, times the stiffness when the loop measures a
/// spring's torque): the roots of the closed loop's characteristic polynomial
/// `J s^3 + (b + G kd) s^2 + (k + G kp) s + G ki`, less a real root within 5 % of a real zero
/// of the PID (`kd s^2 + kp s + ki`). Such a root is the integral's slow pole, which the
/// controller's zero nearly cancels: it carries almost nothing of a disturbance (in the
/// study's position loop a pole at -1.0175/s beside a zero at -1.0155/s, its share of a
/// displaced sample's effect about 0.2 %, of a held command's about 1.2 %). The study's SEA:
/// the position loop 60.6/s (time constant 16.5 ms), the torque loop 10.6/s (94 ms; poles
/// -22.9 and -10.6 +- 28.5j; the load side alone against the spring: with the actuation side
/// free the coupled loops' slowest mode is 9.7/s, and the derivative filters and the period's
/// delay, left out, make the modes faster). Panics on an unstable loop.
pub fn slowest_decay(mass: [f64; 3], loop_gain: f64, (kp, ki, kd): (f64, f64, f64)) -> f64 {
    let [inertia, damping, stiffness] = mass;
    // The monic cubic s^3 + a2 s^2 + a1 s + a0.
    let a2 = (damping + loop_gain * kd) / inertia;
    let a1 = (stiffness + loop_gain * kp) / inertia;
    let a0 = loop_gain * ki / inertia;
    let cubic = |s: f64| ((s + a2) * s + a1) * s + a0;
    // A real root, by bisection between the Cauchy bound and 0 (a0 >= 0: the cubic is not
    // positive below the bound and not negative at 0).
    let (mut lo, mut hi) = (-(1.0 + a2.abs().max(a1.abs()).max(a0.abs())), 0.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cubic(mid) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let real = 0.5 * (lo + hi);
    // The other two: the quadratic left by dividing out (s - real).
    let b1 = a2 + real;
    let b0 = a1 + real * b1;
    let discriminant = b1 * b1 - 4.0 * b0;
    let mut modes = vec![(real, true)];
    if discriminant < 0.0 {
        modes.push((-0.5 * b1, false));
    } else {
        modes.push((0.5 * (-b1 + discriminant.sqrt()), true));
        modes.push((0.5 * (-b1 - discriminant.sqrt()), true));
    }
    let zeros: Vec<f64> = if kd == 0.0 {
        vec![-ki / kp]
    } else if kp * kp >= 4.0 * kd * ki {
        let d = (kp * kp - 4.0 * kd * ki).sqrt();
        vec![(-kp + d) / (2.0 * kd), (-kp - d) / (2.0 * kd)]
    } else {
        Vec::new()
    };
    let decay = modes
        .iter()
        .filter(|&&(p, is_real)| {
            !(is_real && zeros.iter().any(|z| (p - z).abs() <= 0.05 * z.abs() + 1e-9))
        })
        .map(|&(p, _)| -p)
        .fold(f64::INFINITY, f64::min);
    assert!(
        decay > 0.0 && decay.is_finite(),
        "the loop is not stable: slowest decay {decay}/s"
    );
    decay
}

/// The decay rates of the study's SEA loops' slowest modes \[1/s\]: the position loop (the
/// actuation side under the test motor) and the torque loop (the load side against the spring,
/// the actuation side held, under the load motor).
pub fn sea_loop_decays() -> (f64, f64) {
    use kneebench_harness::study::{
        ACTUATION_DAMPING, ACTUATION_INERTIA, Actuator, LOAD_DAMPING, LOAD_INERTIA,
        LOAD_TORQUE_PER_AMPERE, SPRING_STIFFNESS, StudyGains, TEST_TORQUE_PER_AMPERE,
    };
    let gains = StudyGains::for_actuator(Actuator::Sea);
    let position = slowest_decay(
        [ACTUATION_INERTIA, ACTUATION_DAMPING, 0.0],
        TEST_TORQUE_PER_AMPERE,
        gains.position,
    );
    let torque = slowest_decay(
        [LOAD_INERTIA, LOAD_DAMPING, SPRING_STIFFNESS],
        LOAD_TORQUE_PER_AMPERE * SPRING_STIFFNESS,
        gains.torque,
    );
    (position, torque)
}

/// [`slowest_decay`] against closed forms: a PD loop around a mass-damper is the second-order
/// `s^2 + (b + kd) s + kp` (its integral-free root at 0 is the PID's zero there), decaying at
/// half its damping when underdamped and at its slower real root when overdamped; a real pole
/// far from the PID's zeros is kept; and the study's SEA loops decay as the doc comment says.
#[cfg(test)]
#[test]
fn the_loops_slowest_decay_is_the_closed_forms() {
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs();
    // s (s^2 + 2 s + 100): roots 0 and -1 +- 9.95j.
    assert!(close(
        slowest_decay([1.0, 1.0, 0.0], 1.0, (100.0, 0.0, 1.0)),
        1.0
    ));
    // s (s^2 + 10 s + 16): roots 0, -2, -8.
    assert!(close(
        slowest_decay([1.0, 10.0, 0.0], 1.0, (16.0, 0.0, 0.0)),
        2.0
    ));
    // (s + 1)(s + 2)(s + 3) = s^3 + 6 s^2 + 11 s + 6, the PID's zeros at -2 +- 1.41j: all three
    // kept, the slowest -1.
    assert!(close(
        slowest_decay([1.0, 5.0, 7.0], 1.0, (4.0, 6.0, 1.0)),
        1.0
    ));
    let (position, torque) = sea_loop_decays();
    assert!((position - 60.6).abs() < 0.05, "{position}");
    assert!((torque - 10.6).abs() < 0.05, "{torque}");
}

/// Each row's stall of a `BenchHardware` run, `lastLateness + lastReplyTime` of its component
/// `component` (how late the row's deadline was and how long its sample took to arrive: how
/// far behind its nominal time the row's sample was taken) \[s\]; `None` when the run did not
/// record both. Row 0 is the initial sample.
pub fn row_stalls(run: &kneebench_harness::Results, component: &str) -> Option<Vec<f64>> {
    let lateness = run.column(&format!("{component}.lastLateness"))?;
    let reply = run.column(&format!("{component}.lastReplyTime"))?;
    Some(lateness.iter().zip(&reply).map(|(l, r)| l + r).collect())
}

/// Each of `stalls` less the run's mean stall (over the rows after the initial one), none below
/// zero: what a row's stall displaced beyond the steady shift that every row has (a loaded
/// host's mean stall is a sustained delay, which the comparisons allow for on their own).
pub fn beyond_mean(stalls: &[f64]) -> Vec<f64> {
    let mean = mean_stall(stalls);
    stalls.iter().map(|s| (s - mean).max(0.0)).collect()
}

/// The mean of `stalls` over the rows after the initial one (row 0 is the initial sample, no
/// step's); 0 without such a row.
pub fn mean_stall(stalls: &[f64]) -> f64 {
    let rest = stalls.get(1..).unwrap_or_default();
    if rest.is_empty() {
        0.0
    } else {
        rest.iter().sum::<f64>() / rest.len() as f64
    }
}

/// `values` (one per row, `period` apart) carried on at `decay` \[1/s\]: row `k` holds the
/// largest of `values[j] exp(-decay (k - j) period)` over `j <= k`. The largest and not the
/// sum: a host's lateness is measured against the fixed schedule, so a run of late rows is one
/// lag that each of its rows holds whole, not stalls that add up.
pub fn carried(values: &[f64], decay: f64, period: f64) -> Vec<f64> {
    let fade = (-decay * period).exp();
    let mut carried = 0.0f64;
    values
        .iter()
        .map(|&v| {
            carried = v.max(carried * fade);
            carried
        })
        .collect()
}

#[cfg(test)]
#[test]
fn a_stall_is_carried_at_the_decay_and_the_largest_is_kept() {
    let fade = (-10.0f64 * 1e-3).exp();
    let rows = carried(&[0.0, 2e-3, 0.0, 1e-3, 5e-4, 0.0], 10.0, 1e-3);
    let expected = [
        0.0,
        2e-3,
        2e-3 * fade,
        1e-3f64.max(2e-3 * fade * fade),
        2e-3 * fade.powi(3),
        2e-3 * fade.powi(4),
    ];
    for (k, (a, b)) in rows.iter().zip(expected).enumerate() {
        assert!((a - b).abs() <= 1e-15, "row {k}: {a} vs {b}");
    }
    // A later, larger stall takes over.
    assert_eq!(carried(&[1e-3, 3e-3], 10.0, 1e-3)[1], 3e-3);
    assert!(carried(&[], 10.0, 1e-3).is_empty());
}

#[cfg(test)]
#[test]
fn a_stall_beyond_the_mean_is_what_the_mean_does_not_cover() {
    // The initial row is not in the mean: rows 1-4 average 1e-4.
    let beyond = beyond_mean(&[5e-3, 1e-4, 0.0, 1e-4, 2e-4]);
    let expected = [5e-3 - 1e-4, 0.0, 0.0, 0.0, 1e-4];
    for (k, (a, b)) in beyond.iter().zip(expected).enumerate() {
        assert!((a - b).abs() <= 1e-15, "row {k}: {a} vs {b}");
    }
    assert_eq!(beyond_mean(&[3e-4]), vec![3e-4]);
    assert!(beyond_mean(&[]).is_empty());
}
