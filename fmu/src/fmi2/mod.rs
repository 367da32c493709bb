//! The generic FMI 2.0 co-simulation glue: C types, exported functions, instance state machine
//! and logging. Models never see anything in here.

pub mod export;
#[cfg(test)]
mod free_tests;
pub mod instance;
mod live;
pub mod logging;
#[cfg(test)]
mod panic_tests;
#[cfg(test)]
mod refusal_tests;
mod step_args;
#[cfg(test)]
mod structure_tests;
pub mod types;
mod value_tables;
