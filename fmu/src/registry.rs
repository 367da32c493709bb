//! The models this binary serves, found by GUID in `fmi2Instantiate`.
//!
//! One cdylib serves every model; the packager copies it into each FMU under the model's
//! identifier. [`export_models!`](crate::export_models) lists the models once.

use std::borrow::Cow;
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
    /// `documentation/index.html`, rendered on first use (only packaging needs it, and it is the
    /// costliest part of the description to build).
    documentation: OnceLock<String>,
    /// Renders [`Self::documentation`].
    render_documentation: fn() -> String,
    /// Per base type (Real, Integer/Enumeration, Boolean, String), value reference -> 1 + index
    /// in the declaration, 0 when unknown. Dense, because it is read on every get and set.
    pub index: [Vec<u32>; 4],
}

impl ModelInfo {
    /// `documentation/index.html`.
    pub fn documentation(&self) -> &str {
        self.documentation.get_or_init(self.render_documentation)
    }

    /// The declaration index of value reference `vr` of base type `tag`.
    #[inline]
    pub fn find(&self, tag: u8, vr: u32) -> Option<usize> {
        let table = self.index.get(tag as usize)?;
        let found = *table.get(vr as usize)?;
        found.checked_sub(1).map(|i| i as usize)
    }
}

/// Highest value reference a model may declare (the lookup tables are dense).
pub const MAX_VALUE_REFERENCE: u32 = 1 << 16;

/// One exported model.
pub struct ModelEntry {
    /// `modelIdentifier`.
    pub identifier: &'static str,
    build: fn() -> ModelInfo,
    instantiate: fn(&'static ModelInfo, Logger) -> Box<dyn FmiInstance>,
    /// Text of the reference-run inputs (CSV) for `extra/`, if the model has inputs.
    pub reference_inputs: fn() -> Option<String>,
    /// Built on first use; released when the library is unloaded (`crate::release`).
    info: crate::release::Once<ModelInfo>,
}

fn build<M: Model>() -> ModelInfo {
    let (description, xml) = model::model_description_with_xml::<M>();
    let mut index: [Vec<u32>; 4] = Default::default();
    for (i, v) in M::variables().iter().enumerate() {
        assert!(
            v.value_reference < MAX_VALUE_REFERENCE,
            "{}: value reference {} of {} is above {MAX_VALUE_REFERENCE}",
            M::IDENTIFIER,
            v.value_reference,
            v.name
        );
        let table = &mut index[crate::fmi2::instance::base_type_tag(v) as usize];
        let vr = v.value_reference as usize;
        if table.len() <= vr {
            table.resize(vr + 1, 0);
        }
        table[vr] = i as u32 + 1;
    }
    ModelInfo {
        index,
        xml,
        guid: description.guid.clone(),
        documentation: OnceLock::new(),
        render_documentation: model::documentation_html::<M>,
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
            info: crate::release::Once::new(),
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
    find_by_guid_hinted(guid, None)
}

/// The model whose GUID is `guid`, trying the model named `likely` first: a model's GUID is
/// known only once its description is built (it hashes the XML), so the hint spares building
/// the others when it is right; when it is wrong or absent every model is tried.
pub fn find_by_guid_hinted(guid: &str, likely: Option<&str>) -> Option<&'static ModelEntry> {
    find_in(&crate::MODELS, guid, likely)
}

/// The model whose GUID is `guid`: first among the models already built (no building), then
/// the models `hints` name, in turn (a hint is computed only when the ones before it missed),
/// then every model.
pub fn find_by_guid_with_hints<'a>(
    guid: &str,
    hints: impl Iterator<Item = Option<Cow<'a, str>>>,
) -> Option<&'static ModelEntry> {
    find_with(&crate::MODELS, guid, hints)
}

/// [`find_by_guid_hinted`] among `models`.
fn find_in(
    models: &'static [ModelEntry],
    guid: &str,
    likely: Option<&str>,
) -> Option<&'static ModelEntry> {
    find_with(models, guid, std::iter::once(likely.map(Cow::Borrowed)))
}

/// [`find_by_guid_with_hints`] among `models`.
fn find_with<'a>(
    models: &'static [ModelEntry],
    guid: &str,
    hints: impl Iterator<Item = Option<Cow<'a, str>>>,
) -> Option<&'static ModelEntry> {
    if let Some(built) = models
        .iter()
        .find(|m| m.info.get().is_some_and(|i| i.guid == guid))
    {
        return Some(built);
    }
    for hint in hints.flatten() {
        if let Some(entry) = models.iter().find(|m| m.identifier == hint)
            && entry.info().guid == guid
        {
            return Some(entry);
        }
    }
    models.iter().find(|m| m.info().guid == guid)
}

/// The model whose identifier is `identifier`.
pub fn find_by_identifier(identifier: &str) -> Option<&'static ModelEntry> {
    crate::MODELS.iter().find(|m| m.identifier == identifier)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_guid_is_found_whatever_the_hint() {
        for entry in crate::MODELS.iter() {
            let guid = &entry.info().guid;
            let others = crate::MODELS.iter().map(|m| Some(m.identifier));
            for hint in others.chain([None, Some("NoSuchModel"), Some("")]) {
                let found = find_by_guid_hinted(guid, hint).map(|m| m.identifier);
                assert_eq!(found, Some(entry.identifier), "hint {hint:?}");
            }
        }
        // The right hint builds the hinted model's description only (entries of this test's
        // own, so no other test has built them).
        static ENTRIES: [ModelEntry; 3] = [
            ModelEntry::of::<crate::models::gait::GaitReference>(),
            ModelEntry::of::<crate::models::pid::PidController>(),
            ModelEntry::of::<crate::models::clutch_scheduler::ClutchScheduler>(),
        ];
        let guid = &find_by_identifier("ClutchScheduler").unwrap().info().guid;
        let found = find_in(&ENTRIES, guid, Some("ClutchScheduler")).unwrap();
        assert_eq!(found.identifier, "ClutchScheduler");
        assert!(ENTRIES[0].info.get().is_none() && ENTRIES[1].info.get().is_none());
        // Without it every model before the right one is built.
        let guid = &find_by_identifier("PidController").unwrap().info().guid;
        assert_eq!(
            find_in(&ENTRIES, guid, None).unwrap().identifier,
            "PidController"
        );
        assert!(ENTRIES[0].info.get().is_some());
        let unknown = "{00000000-0000-0000-0000-000000000000}";
        assert!(find_by_guid_hinted(unknown, Some(crate::MODELS[0].identifier)).is_none());
        assert!(find_by_guid(unknown).is_none());
    }
}
