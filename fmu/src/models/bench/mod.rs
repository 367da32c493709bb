//! # BenchPlant: the knee-actuator test bench
//!
//! Plain-Rust physics of the bench of `shared/bench-model.md` (sections 1-4 and 7-9), without
//! FMI. One model covers the three configurations DA, SEA and CSEA.
//!
//! ## Choosing the configuration
//! The FMU's `configuration` parameter selects it: `0` = DA, `1` = SEA (the default), `2` =
//! CSEA. It is an FMI `Integer` (bounded to [0, 2], the items named in its description), not an
//! `Enumeration`, like every mode of every kneebench FMU (`frictionModel`, the driver modes):
//! libcosim and the tools built on it ignore FMI 2.0 Enumeration variables, so an SSP binding to
//! an Enumeration `configuration` failed there and a DA ran as the default SEA, and FMI 2.0
//! allows no Integer alias of an Enumeration parameter. Any importer sets it by value;
//! kneebench also takes the item's name (`--param plant.configuration=DA`). A value that is no
//! item is refused.
//!
//! ## Equations
//! Two rotational bodies reflected to the knee axis (positive = extension):
//!
//! ```text
//! I1 w1' + c1 w1 + k (theta1 - theta2) = i_HD Km1 i1 + F1      (actuation side)
//! I2 w2' + c2 w2 + k (theta2 - theta1) = i_RED Km2 i2 + F2     (load side)
//! L1 i1' = V1 - R1 i1 - Ke1 i_HD w1,   L2 i2' = V2 - R2 i2 - Ke2 i_RED w2
//! ```
//!
//! `F1`, `F2` are the friction torques (below) and, on side 1, the clutch. The viscous terms
//! c1, c2 are always present. **DA** is modelled as a stiff coupling: the blocked spring leaves
//! the harmonic drive's torsional stiffness, `k_DA` = 1.3e4 N m/rad (parameter
//! `direct_coupling_stiffness`), between the halves; the exact discretisation handles the
//! resulting 193 rad/s mode at any step, and below ~20 rad/s the response equals the rigid
//! body `1/((I1+I2)s + c1+c2)` to within 1 %. SEA and CSEA use `k` = 340.54 N m/rad; CSEA is
//! SEA with the clutch available (the clutch input acts in every configuration; it is the
//! scheduler's job to use it in CSEA only).
//!
//! ## Drivers
//! * **Voltage mode**: the command is the armature voltage \[V\], clipped to +-supply (24 V test,
//!   48 V load). The driver does not regulate current; the actual current exceeding the driver
//!   limit (15 A / 6 A) trips the `TestCurrent` / `LoadCurrent` interlock (over-current fault).
//! * **Current mode**: the command is the current set value \[A\], clipped to +-limit. The
//!   driver's current loop is an ideal first-order loop, `tau_c i' = i_ref - i`
//!   (`current_loop_time_constant`, default 0.25 ms, i.e. ~640 Hz bandwidth, realised by a
//!   PI-with-back-emf-feed-forward loop), with the voltage it needs,
//!   `V = R i + Ke w_m + (L/tau_c)(i_ref - i)`, limited to +-supply: when the demand exceeds
//!   the supply the armature runs at +-supply (a saturation mode entered and left as located
//!   events). A torque set value is converted with [`current_for_motor_torque`].
//! * A **disabled** driver holds zero current through its loop (so its current decays with
//!   tau_c).
//! * The load driver's **regenerated power** `max(-V2 i2, 0)` above `load_regen_power_limit`
//!   (5 W) trips `RegenPower`. The spec gives no braking limit for the test driver.
//! * The load motor's back-emf constant is `Ke2` = `Km2` = 0.114 (SI units), not the table's
//!   0.145: see "Fidelity against the bench".
//!
//! ## Friction ([`FrictionModel`])
//! * `Off`: no friction elements (viscous c1, c2 and the clutch remain).
//! * `CoulombViscous`: Coulomb friction `Tfr,static1` = 5 N m on side 1 and `Tfr,static2` =
//!   0.35 N m on side 2, equal static and sliding levels.
//! * `Exponential`: `T = [a0 + a1 e^{-b1|w|} + a2 (1 - e^{-b2|w|})] sign(w)` on both sides,
//!   replacing the Coulomb term (c stays in the mechanics). Fit of the defaults: stiction
//!   `a0 + a1 = Tfr,static`, a 20 % Stribeck drop (`a1 = 0.2 Tfr,static`, `b1` = 20 s/rad, i.e.
//!   a Stribeck speed of 0.05 rad/s), growth rate `b2` = 2 s/rad, and `a2` chosen so that for a
//!   0.5 Hz sinusoid of 30 deg amplitude (peak 1.645 rad/s) the first harmonic of the law equals
//!   that of Coulomb `Tfr,static`: `a2 = a1 (1 - J(b1 W))/(1 - J(b2 W))`, `J(z) =
//!   int_0^{pi/2} e^{-z sin p} sin p dp`. The law then dissipates the same energy per 0.5 Hz
//!   cycle as Coulomb `Tfr,static`, and with c unchanged the identified pair (Tfr, c) is
//!   reproduced at 0.5 Hz. Side 1: a0 = 4, a1 = 1, a2 = 1.117927; side 2: a0 = 0.28, a1 = 0.07,
//!   a2 = 0.07825489.
//! * `HdLossSurface`: side 1 uses the steady-state harmonic-drive loss surface of
//!   `shared/data/hd-loss-surface.csv` (`x` = load torque at the output, `i_RED Km2 i2`; `y` =
//!   omega1); side 2 keeps Coulomb `Tfr,static2`. Arguments are clamped to |y| <= 150 deg/s and
//!   -10 <= x <= 15 N m (the largest box around the gait's load range, -4.7..9 N m, in which the
//!   fitted surface stays dissipative; at |x| = 20 it turns positive), and every clamped
//!   evaluation is counted (`hd_surface_clamp_count`). The study's dynamic term
//!   `(I_test + I_load) alpha` is not added: the inertias are already in the mechanics. The
//!   surface's own speed growth overlaps c1; set c1 lower if the surface alone should carry the
//!   losses.
//!   The surface's coefficients are parameters, `hdLossPositiveSpeed[n]` (omega1 >= 0) and
//!   `hdLossNegativeSpeed[n]` (omega1 < 0), n = 1..21 the term `p_ij x^i y^j` of row n of the
//!   csv (p00, p10, p01, p20, p11, p02, ..., p05; each description names its term), with the
//!   csv's values as defaults, so that `kneebench identify` can fit them to a bench (from
//!   `kneebench experiment map` logs recorded with this law) and a parameter set can carry them.
//!   The names are FMI 2.0 structured array elements, 1-based as Modelica tools write them (the
//!   FMU declares the flat convention, for which they are plain names). They carry no unit
//!   attribute: each term has its own unit, N.m (N.m)^-i (rad/s)^-j, which an importer could
//!   only convert through 21 unit definitions of no physical meaning; the polynomial is an
//!   empirical fit in fixed units (x in N.m, y in rad/s, value in N.m), stated in every
//!   description. Changing one takes effect at the next step, like every tunable parameter.
//!
//! ## Stick-slip
//! A switched model per body: **sliding** with friction of sign `-direction`, or **stuck**
//! (`w = 0` exactly, angle frozen bit for bit). A sliding body whose velocity reaches zero
//! (a located event) sticks if the net non-friction torque `D` on it is within its static
//! capacity (friction stiction plus, on side 1, the clutch's 120 N m), else it slides on in the
//! direction of `D`. A stuck body breaks away when `D` exceeds the capacity (located event).
//! Both bodies are coupled through the spring inside each segment, so one can be stuck while
//! the other moves. There is no velocity deadband, so nothing drifts or chatters at any step.
//! Speed-dependent friction laws are held over a segment at the average of their start and
//! predicted end values (second order in the internal step); Coulomb friction is exact.
//!
//! ## Clutch
//! `clutch_engage` is sampled at the start of each communication step (engage and release take
//! effect there). Engaged, it is a friction element on side 1 of `0.75 N m x i_HD = 120 N m`
//! (motor side x ratio) with the stick-slip treatment above, so a sliding clutched body comes to
//! rest at a located instant inside the step. It draws `clutch_power` (6 W) while engaged.
//!
//! ## Numerics
//! Within a segment the plant is linear with constant inputs (driver inputs are sampled and held
//! over the communication step, friction held as above). Each internal sub-step (communication
//! step split into equal parts of at most `max_internal_step`, 1 ms) is integrated exactly:
//! `exp(M h)` and the Gramians of the quadratic energy integrals (Taylor series at `h / 2^s`,
//! Gauss-Legendre on the series for the Gramians, then doubling) are cached per (mode, h), in
//! the plant and process-wide (a discretisation costs about as much as a hundred steps, and
//! every run with the same parameters meets the same few modes). A common rotation of both
//! bodies changes no velocity or current, so the energy integrals are quadratic forms in the
//! spring deflection and the other states (45 products per step instead of 55).
//! Events (stick, break-away, current-loop saturation, interlocks) are tested at the end of the
//! sub-step; when one fires, the sub-step is re-done with a Taylor expansion of the exact flow,
//! the event is located with the Illinois method to rounding, and integration restarts from the
//! event in the new mode. The electrical time constants (0.2-0.8 ms) are therefore no stability
//! or accuracy issue at 1 ms or 0.1 s steps.
//!
//! Outputs are computed when read, by group (read off the state; the energies; the sensors'
//! readings; those that need the held mode, such as voltages, powers and accelerations): an
//! importer that reads a few signals after each step pays for their group only.
//!
//! ## Interlocks ([`Interlock`])
//! Each trips when its quantity strictly exceeds the threshold, located inside the step; the
//! state is stopped at the trip instant and latched, after which `step` returns the trip and
//! does nothing (safe state: commands zeroed, drivers disabled, clutch released).
//! * `SpringDeflection`: |theta1 - theta2| > 5 deg.
//! * `TestMotorTorque`: the test motor's torque **past the harmonic drive**, i.e. the torque
//!   the shaft carries, |k (theta1 - theta2)| (the torque transducer's quantity), above 20 N m.
//!   `LoadMotorTorque`: the load motor's output torque |i_RED Km2 i2| above 20 N m.
//!   Interpretation, to be confirmed by the bench owner: the bench facts say "either motor
//!   torque outside [-20, 20] N m". Motor-shaft torques cannot reach it (15 A x 0.037 =
//!   0.56 N m). The test motor's output torque i_HD Km1 i1 on the bench's gait (2.5 s, 60 deg,
//!   9 N m peak external torque) reaches about 36 N m, 28 N m of it the harmonic drive's own
//!   viscous loss c1 omega1 at the gait's 2.3 rad/s: since the bench ran that gait, its
//!   interlock cannot have watched i_HD Km1 i1. The drive's losses and the clutch (on its input
//!   side) stay inside the actuator; what leaves it is the shaft torque, which peaks at about
//!   11-16 N m on that gait (the ground reaction's 9 N m plus the load side's dynamics). This
//!   reading no longer rests on the torque scaling (see "Fidelity against the bench"): with
//!   the earlier 17.5 N m ground reaction the shaft came within 0.6 N m of the limit, now it
//!   keeps a 4-9 N m margin and the viscous-loss argument alone carries it.
//! * `TestCurrent` / `LoadCurrent`: |i| > 15 A / 6 A (reachable in voltage mode, or when a
//!   saturated current loop is back-driven).
//! * `RegenPower`: load driver absorbing more than 5 W.
//! * `EmergencyStop`: the input, at the start of the step.
//!
//! The watchdog ("a control period missed") belongs to the hardware FMU, not the plant.
//!
//! ## Sensors
//! See the `sensors` module's docs: quantised encoders (2000 counts per motor revolution),
//! torque transducer on the spring torque and load cell on the test motor's output torque, both
//! as raw volts and as torque by the bench's calibration; supply dividers; ACS712 voltages.
//! The calibration gains b (`transducerGain`, `loadCellGain`; published -8 mV and 1 mV) must be
//! at least 1e-6 V in magnitude: the myRIO resolves about 5 mV (12 bits over +-10 V), so a
//! smaller gain could never have been calibrated, and the conversion back to torque,
//! (m g Lg / b)(V - a), stays finite (a subnormal gain made it NaN).
//!
//! ## Energy (§9)
//! `P_test + P_load + P_HD = dE_k/dt + dE_p/dt` with `P_test = i_HD Km1 i1 w1`,
//! `P_load = i_RED Km2 i2 w2`, `P_HD = -c1 w1^2 - c2 w2^2 + F1 w1 + F2 w2 <= 0`; electrical
//! `P_el = V i = R i^2 + d(L i^2/2)/dt + Ke w_m i` per driver, total = both + 7 W offset + 6 W
//! clutch. Integrals since the start are exact (Gramians / polynomial integrals of the exact
//! flow); "consumed" is the integral of the positive part. Where a power changes sign inside a
//! regular sub-step, the split uses a cubic Hermite model of the power over the sub-step (from
//! its exact end values and slopes, corrected to the exact signed integral; error O(h^4) per
//! crossing); in sub-steps cut by events the split is exact (roots of the power polynomial).
//! Sign changes are detected at sub-step ends; a double sign change inside one sub-step is
//! treated as none. `kinetic_energy_change` / `potential_energy_change` are relative to the
//! start at rest. `total_electrical_power` / `totalElectricalEnergy` add **both** drivers
//! (`V1 i1 + V2 i2`, signed, so a regenerating load driver counts negative) plus the offset and
//! the clutch; the bench's electrical energy counts the test driver only (below).
//!
//! The study (`kneebench study`, the harness's `study::analysis`) reports the bench's own
//! quantities (section 10), each in joules per gait cycle, the difference of the integral
//! outputs over each complete cycle averaged over the cycles:
//!
//! * **Test-motor mechanical energy** (eq. 71) (J per cycle): the integral of
//!   `testMechanicalPower` = `i_HD Km1 i1 w1`, the actuation (harmonic-drive output) shaft's
//!   velocity times the test motor's torque there, what the load cell measures, before the
//!   drive's losses.
//! * **Bench electrical energy** (eq. 70) (J per cycle): `testElectricalEnergy +
//!   offsetEnergy + clutchEnergy`, the test driver's draw `V1 i1` from its 24 V supply (a
//!   loss-free driver), the 7 W hardware offset and the clutch's 6 W while engaged; not the
//!   load motor's 48 V supply.
//! * **Harmonic-drive loss E_HD** (J per cycle): `actuationLossEnergy`, the integral of
//!   `-c1 w1^2 + F1 w1` (<= 0), the actuation side's dissipation.
//! * **Load side** (J per cycle), reported apart: `loadMechanicalEnergy` (`i_RED Km2 i2 w2`,
//!   positive while the load motor drives the shaft), `loadElectricalEnergy` (`V2 i2`),
//!   `loadLossEnergy` (<= 0).
//! * **E_k stored** (Table 13's E_k) (J per cycle): the integral of the positive part of
//!   dE_k/dt, `E_k = (I1 w1^2 + I2 w2^2)/2`, i.e. the kinetic energy stored (and released
//!   again) within the cycle, summed from the positive increments of the 1 ms samples of
//!   `kineticEnergy`.
//! * **E_p stored** (Table 13's E_p) (J per cycle): the same for the spring's
//!   `E_p = k (theta1 - theta2)^2 / 2` (`potentialEnergy`).
//! * **Net dE_k, dE_p** (J per cycle): the change over the cycle (zero on a periodic cycle),
//!   what closes the balance `test + load + E_HD + load loss = dE_k + dE_p`.
//!
//! ## Initial state
//! The plant starts at rest at angle 0 with zero currents. The stick/slip rule is applied to
//! that state at once (and again whenever the parameters change), so the outputs read before
//! the first step show it: with friction, both bodies stuck, no friction torque, no
//! acceleration; the t = 0 row equals the state the plant holds.
//!
//! ## Fidelity against the bench
//! The bench published energies per gait cycle (bench facts, section 10). `kneebench study`
//! runs the same experiments (scenario `bench-full`: 60 deg; `bench-clutch`: 50 deg, impedance
//! control, clutch in stance) and prints each value next to the twin's with the ratio. Every
//! figure below names where it comes from; "the run" is `kneebench study --fmus out/fmus
//! --scenario bench-full` (4 cycles, the last 3 analysed; the same numbers as
//! `bash scripts/run.sh`), a variant adds `--param` options, and a peak of
//! `plant.loadRegeneratedPower` is the largest value in the run's CSVs after the first cycle.
//! What changed in the model and why, and what remains:
//! * **Torque scaling.** The bench scaled the gait "such that the maximum applied external
//!   torque is 9 N m". The twin takes 9 N m as the largest magnitude of the applied external
//!   torque, the ground reaction `-kneeTorqueReference`: the normalised series' largest
//!   magnitude is its minimum, -1.9356 (the GaitReference test
//!   `normalised_gait_has_the_documented_extremes`), so the scale is 9/1.9356
//!   (`GaitReference`'s `kneeTorqueAmplitude` is that peak). Read as the series' own maximum
//!   (+1.0), the scale would be 9 and the external torque would reach 9 x 1.9356 = 17.4 N m
//!   at its other extreme; which reading the bench meant is tied to the sign question below.
//! * **Load motor Ke2 = Km2.** The published Ke2 = 0.145 V s/rad against Km2 = 0.114 N m/A would
//!   make the load motor's conversion create energy: braking, it would deliver 0.145/0.114 =
//!   1.27 times the mechanical power it absorbs as electrical power. In SI units Ke = Km for any
//!   motor (the test motor's pair agrees, 0.037); 0.114 matches the EC 60 flat's catalogue
//!   torque constant, so 0.145 is taken as a misprint. This lowers the regenerated power the
//!   load driver sees by the same 27 %.
//! * **What the load side does.** With the twin's pairing the knee absorbs energy over a gait
//!   cycle, so the ground reaction does net positive work on the shaft: along the reference,
//!   9/1.9356 N m x 1.047 rad (60 deg) x 0.6967 = 3.4 J per cycle (0.6967 = -the cycle
//!   integral of the normalised torque times the normalised angle's rate, computed from
//!   `data/gait-fourier.csv`); in the
//!   run the load motor delivers 4.5 J (SEA) and 4.7 J (DA), of which the load side's own
//!   losses take 4.0 J. The bench's balance (64.76 J in, 51.57 J lost in the drive) leaves
//!   about 13 J that its load side absorbed, which this ground reaction cannot. (The study's
//!   earlier torque plan also made the load motor push along the motion to keep the shaft
//!   torque under the interlock; with the corrected scaling the load motor applies the bare
//!   ground reaction.)
//! * **Sign of the load: the evidence, undecided.** The twin is not changed; the evidence
//!   either way, with runs of the bench-full scenario:
//!   - The frames. The angle series is positive in flexion: its peak 1.0 at 71.5 % of the
//!     cycle is the swing's flexion, and it rises to 0.25 in loading response (13 %). The
//!     torque series reaches its extreme, -1.94, at 13 %, in loading response, where a human
//!     knee's own (internal) moment is extensor. With the bench facts' "Extension torque is
//!     positive", the series is therefore the external torque (the ground reaction's moment,
//!     which flexes the knee in loading response), or equivalently the internal moment in the
//!     angle's flexion-positive frame: the same numbers. In the angle's frame the knee torque
//!     is then +s x series and the ground reaction -s x series, the twin's pairing
//!     (`loadTorqueReference = -kneeTorqueReference`, the facts' "the load motor applies the
//!     ground reaction, i.e. the inverted knee torque"), with which the knee absorbs energy
//!     over the cycle, as a walking knee does. Taken literally instead, as the knee's torque
//!     with extension positive next to an angle positive in flexion (two frames in one
//!     bench), the same words give the opposite pairing, and the load absorbs.
//!   - For the opposite pairing: the bench's own balance needs its load side to absorb about
//!     13 J per cycle. With the ground reaction reversed at the same 9 N m peak
//!     (`--param gait.kneeTorqueAmplitude=-9 --param plant.loadRegenPowerLimit=1000`) the
//!     test motor's energy becomes 55.9 J (DA) and 53.6 J (SEA), ratios 0.87 and 0.83, the
//!     load side absorbing 6.5-6.7 J (2.5-2.7 J the load motor, 4.0 J its losses); with the
//!     series' +1.0 as 9 N m and reversed (`kneeTorqueAmplitude=-17.42`) 59.3 J and 58.4 J,
//!     ratios 0.92 and 0.90, the load side absorbing 9.8-10.1 J. Table 14 comes within 15 %
//!     only so.
//!   - Against it: the bench ran the 60 deg gait at 9 N m (Tables 13, 14), and the facts give
//!     the load driver a 5 W braking limit and say the 50 deg clutch study was chosen because
//!     at higher amplitudes "the drivers could not absorb the braking power". Reversed, the
//!     twin's load driver regenerates up to 6.3-7.1 W at 60 deg (-9) and 11.7-13.9 W
//!     (-17.42), and at 50 deg (`--scenario bench-clutch`, SEA) 6.1 W and 11.6 W: at the armed
//!     5 W (the plant's default) the bench-full runs trip in the first cycle, at 1.34-1.37 s
//!     (-9) and 1.30 s (-17.42; exit code 3, the report names the interlock), so
//!     neither Table 14 nor Table 15 could have been measured; with the twin's pairing the
//!     peak is 0.6-1.2 W at 60 deg (the run) and 0.4 W at 50 deg (SEA). The reversed pairing
//!     also raises the shaft torque to 16.5-18.7 N m (-17.42) against the 20 N m interlock,
//!     and under the clutch study's impedance control the CSEA trips it (both reversed
//!     readings).
//!   - What would decide: the sign of the bench's recorded load-cell or transducer torque
//!     against its encoder angle over a cycle (which of the two motors does net work), or the
//!     load driver's own limit and the load side's losses on the bench (a braking load side
//!     within 5 W needs its losses, not its driver, to take most of the 13 J).
//! * **Electrical energy.** The twin's test motor loses only its copper losses (R1 = 0.608 Ohm)
//!   through a loss-free driver: 77.7 J per cycle (SEA) and 83.7 J (DA) in the run against the
//!   bench's 169.86 J and 168.57 J. The gap (92 J, 37 W on average over the 2.5 s) is not in
//!   the model's data: candidates are the driver's own losses and quiescent draw beyond the 7 W
//!   offset, PWM ripple losses, and the bench's larger mechanical energy; no parameter of the
//!   bench facts is changed to close it.
//! * **Stored energies.** E_k stored with the identified inertias (I1 + I2 = 1.43 kg m^2) is
//!   7.3 J per cycle (SEA) and 7.8 J (DA) in the run, Table 13 gives 40.17 J and 39.68 J; E_p
//!   0.51 J (SEA) against 2.51 J. Both would need about 5 times the inertia's or the
//!   stiffness' energy; the bench's values probably come from spline-differentiated encoder
//!   signals (noise adds to the positive part of dE/dt), which the twin does not model.
//! * **Harmonic-drive loss** agrees within 4-14 % in the run (-49.4 J DA, -44.6 J SEA against
//!   -51.20 J and -51.57 J; c1 and Tfr1 were identified on the bench's gait). The published
//!   steady-state loss surface alone on the same gait (`--param plant.frictionModel=3 --param
//!   plant.actuationDamping=0`) gives -17.1 J (DA) and -15.6 J (SEA), a third of Table 13's
//!   E_HD: the surface alone cannot be what Table 13 integrated.
//! * **The calibration's phase c** (section 8) is the angle between the encoder's zero and
//!   the pendulum's hanging direction during the calibration (it is why the bench converts with
//!   `T = (m g Lg / b)(V - a)`, without c). A running sensor sees torque only, so c is not a
//!   property the plant's sensors can show; `kneebench experiment calibration` emulates the
//!   pendulum hanging `--pendulum-offset` from the zero and recovers that offset as c
//!   (`calibration_recovers_a_b_c_within_1_percent`). The plant's sensors keep their
//!   small-angle form with c as a bias (`sensors` module), a choice the bench's data cannot
//!   distinguish from an exact `V = a + b T / (m g Lg)` by more than that bias (-0.048 N m on
//!   the transducer, +0.090 N m on the load cell).

mod derivatives;
mod friction;
mod hd_loss;
mod mechanics;
mod outputs;
mod params;
pub(crate) mod plant;
mod sensors;
mod state;

#[cfg(test)]
mod tests;

pub use self::derivatives::BenchOutputDerivatives;
pub use self::outputs::{BenchOutputs, REAL_OUTPUTS, SignalGroup, signal_group};
pub use self::params::{BenchParameters, ParameterError};
pub use self::plant::BenchPlant;
pub use self::state::StateError;

use thiserror::Error;

/// Actuator configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Configuration {
    /// Direct actuation: spring blocked, halves coupled by the harmonic drive's stiffness.
    Da,
    /// Series elastic actuation.
    Sea,
    /// Clutched series elastic actuation.
    Csea,
}

impl Configuration {
    /// From the FMU's Integer parameter (0 DA, 1 SEA, 2 CSEA).
    pub fn from_i32(value: i32) -> Option<Self> {
        match value {
            0 => Some(Self::Da),
            1 => Some(Self::Sea),
            2 => Some(Self::Csea),
            _ => None,
        }
    }

    /// The FMU's Integer value.
    pub fn as_i32(self) -> i32 {
        self as i32
    }
}

/// Friction law (module docs, "Friction").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrictionModel {
    /// No friction elements on either side (viscous c1, c2 and clutch remain).
    Off,
    /// Coulomb Tfr,static1 on side 1 and Tfr,static2 on side 2, with stick-slip.
    CoulombViscous,
    /// Exponential Stribeck-like law on both sides, with stick-slip.
    Exponential,
    /// Harmonic-drive loss surface on side 1, Coulomb Tfr,static2 on side 2.
    HdLossSurface,
}

impl FrictionModel {
    /// From the FMU's Integer parameter (0 Off, 1 CoulombViscous, 2 Exponential, 3 HdLossSurface).
    pub fn from_i32(value: i32) -> Option<Self> {
        match value {
            0 => Some(Self::Off),
            1 => Some(Self::CoulombViscous),
            2 => Some(Self::Exponential),
            3 => Some(Self::HdLossSurface),
            _ => None,
        }
    }

    /// The FMU's Integer value.
    pub fn as_i32(self) -> i32 {
        self as i32
    }
}

/// Driver operating mode (module docs, "Drivers").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriverMode {
    /// Command = armature voltage \[V\].
    Voltage,
    /// Command = current set value \[A\].
    Current,
}

impl DriverMode {
    /// From the FMU's Integer parameter (0 Voltage, 1 Current).
    pub fn from_i32(value: i32) -> Option<Self> {
        match value {
            0 => Some(Self::Voltage),
            1 => Some(Self::Current),
            _ => None,
        }
    }

    /// The FMU's Integer value.
    pub fn as_i32(self) -> i32 {
        self as i32
    }
}

/// Current set value \[A\] that makes a motor deliver the motor-shaft torque `torque` [N m]:
/// `torque / Km`. For an output-side torque divide by the gear ratio first.
pub fn current_for_motor_torque(torque: f64, torque_constant: f64) -> f64 {
    torque / torque_constant
}

/// Inputs, sampled at the start of a communication step and held over it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BenchInputs {
    /// Test-motor command: armature voltage \[V\] in voltage mode, current set value \[A\] in
    /// current mode.
    pub test_command: f64,
    /// Load-motor command, same meaning per the load driver's mode.
    pub load_command: f64,
    /// Test driver enabled (a disabled driver holds zero current).
    pub test_enable: bool,
    /// Load driver enabled.
    pub load_enable: bool,
    /// Clutch engaged.
    pub clutch_engage: bool,
    /// Emergency stop pressed (trips at the start of the step).
    pub emergency_stop: bool,
}

/// Inputs or a step size the plant cannot use.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum InputError {
    /// A command is NaN or infinite.
    #[error("input `{name}` is not finite: {value}")]
    NotFinite {
        /// Input name.
        name: &'static str,
        /// Offending value.
        value: f64,
    },
    /// The communication step is not a positive finite number.
    #[error("step size must be positive and finite, got {0}")]
    StepSize(f64),
}

impl BenchInputs {
    /// Checks the commands are finite.
    pub fn validate(&self) -> Result<(), InputError> {
        for (name, value) in [
            ("test_command", self.test_command),
            ("load_command", self.load_command),
        ] {
            if !value.is_finite() {
                return Err(InputError::NotFinite { name, value });
            }
        }
        Ok(())
    }
}

/// A safety interlock of bench-model.md §7.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Interlock {
    /// |theta1 - theta2| above the limit (5 deg).
    SpringDeflection,
    /// Test motor's output-side torque outside +-20 N m.
    TestMotorTorque,
    /// Load motor's output-side torque outside +-20 N m.
    LoadMotorTorque,
    /// Test motor current above the driver limit (15 A).
    TestCurrent,
    /// Load motor current above the driver limit (6 A).
    LoadCurrent,
    /// Load driver absorbing more regenerated power than its limit (5 W).
    RegenPower,
    /// Emergency-stop input.
    EmergencyStop,
}

impl Interlock {
    /// Interlocks checked continuously during integration.
    pub(crate) const CHECKED: [Interlock; 6] = [
        Interlock::SpringDeflection,
        Interlock::TestMotorTorque,
        Interlock::LoadMotorTorque,
        Interlock::TestCurrent,
        Interlock::LoadCurrent,
        Interlock::RegenPower,
    ];

    /// Status code reported by the FMU (0 means no trip).
    pub fn code(self) -> i32 {
        match self {
            Interlock::SpringDeflection => 1,
            Interlock::TestMotorTorque => 2,
            Interlock::LoadMotorTorque => 3,
            Interlock::TestCurrent => 4,
            Interlock::LoadCurrent => 5,
            Interlock::RegenPower => 6,
            Interlock::EmergencyStop => 7,
        }
    }

    /// Inverse of [`Self::code`].
    pub fn from_code(code: i32) -> Option<Self> {
        match code {
            1 => Some(Interlock::SpringDeflection),
            2 => Some(Interlock::TestMotorTorque),
            3 => Some(Interlock::LoadMotorTorque),
            4 => Some(Interlock::TestCurrent),
            5 => Some(Interlock::LoadCurrent),
            6 => Some(Interlock::RegenPower),
            7 => Some(Interlock::EmergencyStop),
            _ => None,
        }
    }

    /// Human-readable name for log messages.
    pub fn name(self) -> &'static str {
        match self {
            Interlock::SpringDeflection => "spring deflection above limit",
            Interlock::TestMotorTorque => "test motor torque outside limit",
            Interlock::LoadMotorTorque => "load motor torque outside limit",
            Interlock::TestCurrent => "test motor current above driver limit",
            Interlock::LoadCurrent => "load motor current above driver limit",
            Interlock::RegenPower => "load driver regenerated power above limit",
            Interlock::EmergencyStop => "emergency stop",
        }
    }
}

/// Result of [`BenchPlant::step`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepOutcome {
    /// The step completed; time advanced by h.
    Completed,
    /// An interlock tripped at `time` (inside this or an earlier step); the state is stopped
    /// there and latched.
    Tripped {
        /// Which interlock.
        interlock: Interlock,
        /// Trip time \[s\].
        time: f64,
    },
    /// Nothing was done: a command was not finite or h was not a positive finite number.
    Rejected(InputError),
}
