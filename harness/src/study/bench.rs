//! What the bench measured (bench facts, section 10) next to what the twin gives for the same
//! experiment: each quantity with the bench's value, the twin's and their ratio.
//!
//! The twin's numbers come from the runs ([`StudyRun::report`]); nothing here is fitted.

use super::{Actuator, EnergyTerms, StudyRun, StudyScenario};

/// A quantity of the bench's energy tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Harmonic-drive loss energy E_HD per cycle \[J\] (Table 13).
    DriveLoss,
    /// Kinetic energy stored and released per cycle \[J\] (Table 13's E_k).
    KineticStored,
    /// Spring energy stored and released per cycle \[J\] (Table 13's E_p).
    PotentialStored,
    /// Test motor's mechanical energy per cycle \[J\] (Tables 14, 15).
    TestMechanical,
    /// Electrical energy per cycle: test supply, 7 W offset, clutch \[J\] (Tables 14, 15).
    BenchElectrical,
    /// The clutch's electrical energy per cycle \[J\] (section 10: "about 7.5 J").
    Clutch,
    /// Fraction of the cycle the clutch is locked (section 10: "about half the cycle").
    ClutchEngaged,
}

impl Quantity {
    /// Label with unit.
    pub fn label(self) -> &'static str {
        match self {
            Quantity::DriveLoss => "harmonic-drive loss E_HD [J]",
            Quantity::KineticStored => "E_k stored and released [J]",
            Quantity::PotentialStored => "E_p stored and released [J]",
            Quantity::TestMechanical => "test-motor mechanical energy [J]",
            Quantity::BenchElectrical => "electrical energy, test supply + offset + clutch [J]",
            Quantity::Clutch => "clutch electrical energy [J]",
            Quantity::ClutchEngaged => "clutch locked [fraction of the cycle]",
        }
    }

    /// The twin's value of this quantity.
    pub fn of(self, e: &EnergyTerms) -> f64 {
        match self {
            Quantity::DriveLoss => e.drive_loss,
            Quantity::KineticStored => e.kinetic_stored,
            Quantity::PotentialStored => e.potential_stored,
            Quantity::TestMechanical => e.test_mechanical,
            Quantity::BenchElectrical => e.bench_electrical,
            Quantity::Clutch => e.clutch,
            Quantity::ClutchEngaged => e.clutch_engaged_fraction,
        }
    }
}

/// One value the bench measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Where it is published (`Table 13`, ...).
    pub source: &'static str,
    /// The experiment it belongs to.
    pub scenario: StudyScenario,
    /// The actuator.
    pub actuator: Actuator,
    /// What it is.
    pub quantity: Quantity,
    /// The published value.
    pub value: f64,
}

const fn m(
    source: &'static str,
    scenario: StudyScenario,
    actuator: Actuator,
    quantity: Quantity,
    value: f64,
) -> Measurement {
    Measurement {
        source,
        scenario,
        actuator,
        quantity,
        value,
    }
}

/// The bench's published energy figures per 2.5 s gait cycle (bench facts, section 10).
pub const MEASURED: [Measurement; 16] = {
    use Actuator::{Csea, Da, Sea};
    use Quantity::*;
    use StudyScenario::{BenchClutch, BenchFull};
    [
        m("Table 13", BenchFull, Sea, DriveLoss, -51.57),
        m("Table 13", BenchFull, Sea, KineticStored, 40.17),
        m("Table 13", BenchFull, Sea, PotentialStored, 2.51),
        m("Table 13", BenchFull, Da, DriveLoss, -51.2),
        m("Table 13", BenchFull, Da, KineticStored, 39.68),
        m("Table 14", BenchFull, Sea, TestMechanical, 64.76),
        m("Table 14", BenchFull, Sea, BenchElectrical, 169.86),
        m("Table 14", BenchFull, Da, TestMechanical, 64.18),
        m("Table 14", BenchFull, Da, BenchElectrical, 168.57),
        m("Table 15", BenchClutch, Csea, TestMechanical, 49.49),
        m("Table 15", BenchClutch, Csea, BenchElectrical, 146.32),
        m("Table 15", BenchClutch, Sea, TestMechanical, 47.43),
        m("Table 15", BenchClutch, Sea, BenchElectrical, 129.51),
        m("section 10", BenchClutch, Csea, Clutch, 7.5),
        m("section 10", BenchClutch, Csea, ClutchEngaged, 0.5),
        m("section 10", BenchClutch, Sea, Clutch, 0.0),
    ]
};

/// A measured value next to the twin's.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// What the bench measured.
    pub measured: Measurement,
    /// The twin's value (NaN when the run completed no cycle).
    pub twin: f64,
}

impl Comparison {
    /// twin / measured (NaN for a measured 0).
    pub fn ratio(&self) -> f64 {
        if self.measured.value == 0.0 {
            f64::NAN
        } else {
            self.twin / self.measured.value
        }
    }
}

/// Every measured value whose experiment and actuator are among `runs`, with the twin's value.
pub fn compare(runs: &[&StudyRun]) -> Vec<Comparison> {
    MEASURED
        .iter()
        .filter_map(|measured| {
            let run = runs
                .iter()
                .find(|r| r.study == measured.scenario && r.actuator == measured.actuator)?;
            Some(Comparison {
                measured: *measured,
                twin: measured.quantity.of(&run.report.energy),
            })
        })
        .collect()
}

/// The comparison as a Markdown table: source, actuator, quantity, bench, twin, ratio.
pub fn comparison_markdown(rows: &[Comparison]) -> String {
    let mut s = String::from(
        "| source | scenario | actuator | quantity | bench | twin | twin / bench |\n|---|---|---|---|---:|---:|---:|\n",
    );
    for c in rows {
        let ratio = c.ratio();
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} |\n",
            c.measured.source,
            c.measured.scenario.name(),
            c.measured.actuator.name(),
            c.measured.quantity.label(),
            number(c.measured.value),
            number(c.twin),
            if ratio.is_finite() {
                format!("{ratio:.2}")
            } else {
                "-".into()
            }
        ));
    }
    s
}

/// A value with three decimals below 10, two above (the tables' own precision).
fn number(v: f64) -> String {
    if v.abs() < 10.0 {
        format!("{v:.3}")
    } else {
        format!("{v:.2}")
    }
}
