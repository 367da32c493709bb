//! The models this binary serves, found by GUID in `fmi2Instantiate`.
//!
//! One cdylib serves every model; the packager copies it into each FMU under the model's
//! identifier. [`export_models!`](crate::export_models) lists the models once.

use std::sync::OnceLock;

use model_description::ModelDescription;

use crate::fmi2::instance::{FmiInstance, Instance};
use crate::fmi2::logging::Logger;
use crate::model::{self, Model};

/// What is generated once per model from its declaration.
#[derive(Debug)]
pub struct ModelInfo {
    /// The typed model description.
    pub description: ModelDescription,
    /// `modelDescription.xml`.
    pub xml: String,
    /// The GUID (also inside `description` and `xml`).
    pub guid: String,
    /// `documentation/index.html`.
    pub documentation: String,
}

/// One exported model.
pub struct ModelEntry {
    /// `modelIdentifier`.
    pub identifier: &'static str,
    build: fn() -> ModelInfo,
    instantiate: fn(&'static ModelInfo, Logger) -> Box<dyn FmiInstance>,
    /// Text of the reference-run inputs (CSV) for `extra/`, if the model has inputs.
    pub reference_inputs: fn() -> Option<String>,
    info: OnceLock<ModelInfo>,
}

fn build<M: Model>() -> ModelInfo {
    let description = model::model_description::<M>();
    ModelInfo {
        xml: description.to_xml(),
        guid: description.guid.clone(),
        documentation: model::documentation_html::<M>(),
        description,
    }
}

fn instantiate<M: Model>(info: &'static ModelInfo, logger: Logger) -> Box<dyn FmiInstance> {
    Box::new(Instance::<M>::new(info, logger))
}

/// Models that provide recorded inputs for their documented reference run.
pub trait ReferenceInputs {
    /// CSV text (`time,<input names>`) of the inputs of the reference run, or `None`.
    fn reference_inputs() -> Option<String> {
        None
    }
}

impl ModelEntry {
    /// The entry of model `M`.
    pub const fn of<M: Model + ReferenceInputs>() -> Self {
        Self {
            identifier: M::IDENTIFIER,
            build: build::<M>,
            instantiate: instantiate::<M>,
            reference_inputs: M::reference_inputs,
            info: OnceLock::new(),
        }
    }

    /// The generated description, XML, GUID and documentation (built on first use).
    pub fn info(&'static self) -> &'static ModelInfo {
        self.info.get_or_init(self.build)
    }

    /// A new instance of this model.
    pub fn instantiate(&'static self, logger: Logger) -> Box<dyn FmiInstance> {
        (self.instantiate)(self.info(), logger)
    }
}

/// Declares the models this binary exports: `export_models!(GaitReference, BenchPlant);`.
#[macro_export]
macro_rules! export_models {
    ($($model:ty),+ $(,)?) => {
        /// Every model this binary serves.
        pub static MODELS: [$crate::registry::ModelEntry; [$(stringify!($model)),+].len()] =
            [$($crate::registry::ModelEntry::of::<$model>()),+];
    };
}

/// The model whose GUID is `guid`.
pub fn find_by_guid(guid: &str) -> Option<&'static ModelEntry> {
    crate::MODELS.iter().find(|m| m.info().guid == guid)
}

/// The model whose identifier is `identifier`.
pub fn find_by_identifier(identifier: &str) -> Option<&'static ModelEntry> {
    crate::MODELS.iter().find(|m| m.identifier == identifier)
}
