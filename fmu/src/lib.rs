//! kneebench FMUs: the FMI 2.0 co-simulation export layer and the bench models.
//!
//! One cdylib serves every model; `fmi2Instantiate` picks the model by GUID. Models are plain
//! Rust structs implementing [`model::Model`] with one declaration of their variables, from
//! which everything else (value references, get/set, `modelDescription.xml`, `ModelStructure`,
//! units, GUID, FMU-state layout, documentation) is generated.

#![warn(missing_docs)]

pub mod fmi2;
pub mod hardware;
pub mod model;
pub mod models;
pub mod registry;
mod release;

export_models!(
    models::gait::GaitReference,
    models::bench_plant::BenchPlantModel,
    models::bench_hardware::BenchHardwareModel,
    models::pid::PidController,
    models::impedance::ImpedanceController,
    models::clutch_scheduler::ClutchScheduler,
);
