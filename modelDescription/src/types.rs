//! The typed FMI 2.0 model description.
//!
//! One Rust type per element of `fmi2ModelDescription.xsd`. Optional XML attributes are `Option`s
//! so that reading and writing back is lossless: an attribute that was absent stays absent, an
//! attribute that was present keeps its value even when it equals the schema default. Use the
//! `*_or_default` helpers where the schema default matters.

/// `fmiModelDescription`: the root element.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelDescription {
    /// `fmiVersion`; always `"2.0"` for the descriptions this crate accepts.
    pub fmi_version: String,
    /// `modelName`.
    pub model_name: String,
    /// `guid`: the fingerprint the binary checks in `fmi2Instantiate`.
    pub guid: String,
    /// `description`.
    pub description: Option<String>,
    /// `author`.
    pub author: Option<String>,
    /// `version`: the model's version.
    pub version: Option<String>,
    /// `copyright`.
    pub copyright: Option<String>,
    /// `license`.
    pub license: Option<String>,
    /// `generationTool`.
    pub generation_tool: Option<String>,
    /// `generationDateAndTime` (xs:dateTime, kept as written).
    pub generation_date_and_time: Option<String>,
    /// `variableNamingConvention`.
    pub variable_naming_convention: Option<VariableNamingConvention>,
    /// `numberOfEventIndicators`.
    pub number_of_event_indicators: Option<u32>,
    /// `ModelExchange`: present when the FMU offers model exchange.
    pub model_exchange: Option<ModelExchange>,
    /// `CoSimulation`: present when the FMU offers co-simulation.
    pub co_simulation: Option<CoSimulation>,
    /// `UnitDefinitions/Unit`.
    pub unit_definitions: Vec<Unit>,
    /// `TypeDefinitions/SimpleType`.
    pub type_definitions: Vec<SimpleType>,
    /// `LogCategories/Category`.
    pub log_categories: Vec<LogCategory>,
    /// `DefaultExperiment`.
    pub default_experiment: Option<DefaultExperiment>,
    /// `VendorAnnotations/Tool`.
    pub vendor_annotations: Vec<ToolAnnotation>,
    /// `ModelVariables/ScalarVariable`, in document order (index = position + 1).
    pub model_variables: Vec<ScalarVariable>,
    /// `ModelStructure`.
    pub model_structure: ModelStructure,
}

/// `variableNamingConvention`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VariableNamingConvention {
    /// `flat`.
    Flat,
    /// `structured`.
    Structured,
}

/// `CoSimulation` capabilities.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CoSimulation {
    /// `modelIdentifier`: the binary's file stem and the C function prefix.
    pub model_identifier: String,
    /// `needsExecutionTool`.
    pub needs_execution_tool: Option<bool>,
    /// `canHandleVariableCommunicationStepSize`.
    pub can_handle_variable_communication_step_size: Option<bool>,
    /// `canInterpolateInputs`.
    pub can_interpolate_inputs: Option<bool>,
    /// `maxOutputDerivativeOrder`.
    pub max_output_derivative_order: Option<u32>,
    /// `canRunAsynchronuously` (the schema's spelling).
    pub can_run_asynchronuously: Option<bool>,
    /// `canBeInstantiatedOnlyOncePerProcess`.
    pub can_be_instantiated_only_once_per_process: Option<bool>,
    /// `canNotUseMemoryManagementFunctions`.
    pub can_not_use_memory_management_functions: Option<bool>,
    /// `canGetAndSetFMUstate`.
    pub can_get_and_set_fmu_state: Option<bool>,
    /// `canSerializeFMUstate`.
    pub can_serialize_fmu_state: Option<bool>,
    /// `providesDirectionalDerivative`.
    pub provides_directional_derivative: Option<bool>,
    /// `SourceFiles/File@name`.
    pub source_files: Vec<String>,
}

/// `ModelExchange` capabilities (read and written, never used by kneebench's own FMUs).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelExchange {
    /// `modelIdentifier`.
    pub model_identifier: String,
    /// `needsExecutionTool`.
    pub needs_execution_tool: Option<bool>,
    /// `completedIntegratorStepNotNeeded`.
    pub completed_integrator_step_not_needed: Option<bool>,
    /// `canBeInstantiatedOnlyOncePerProcess`.
    pub can_be_instantiated_only_once_per_process: Option<bool>,
    /// `canNotUseMemoryManagementFunctions`.
    pub can_not_use_memory_management_functions: Option<bool>,
    /// `canGetAndSetFMUstate`.
    pub can_get_and_set_fmu_state: Option<bool>,
    /// `canSerializeFMUstate`.
    pub can_serialize_fmu_state: Option<bool>,
    /// `providesDirectionalDerivative`.
    pub provides_directional_derivative: Option<bool>,
    /// `SourceFiles/File@name`.
    pub source_files: Vec<String>,
}

/// `Unit`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Unit {
    /// `name`, e.g. `"rad/s"`.
    pub name: String,
    /// `BaseUnit`: the SI exponents and the factor/offset to SI.
    pub base_unit: Option<BaseUnit>,
    /// `DisplayUnit`s.
    pub display_units: Vec<DisplayUnit>,
}

/// `BaseUnit`: exponents of the SI base units, plus factor and offset.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BaseUnit {
    /// `kg` exponent.
    pub kg: Option<i32>,
    /// `m` exponent.
    pub m: Option<i32>,
    /// `s` exponent.
    pub s: Option<i32>,
    /// `A` exponent.
    pub a: Option<i32>,
    /// `K` exponent.
    pub k: Option<i32>,
    /// `mol` exponent.
    pub mol: Option<i32>,
    /// `cd` exponent.
    pub cd: Option<i32>,
    /// `rad` exponent.
    pub rad: Option<i32>,
    /// `factor`.
    pub factor: Option<f64>,
    /// `offset`.
    pub offset: Option<f64>,
}

/// `DisplayUnit`: `value_in_display_unit = factor * value_in_unit + offset`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DisplayUnit {
    /// `name`, e.g. `"deg"`.
    pub name: String,
    /// `factor`.
    pub factor: Option<f64>,
    /// `offset`.
    pub offset: Option<f64>,
}

/// `SimpleType` in `TypeDefinitions`.
#[derive(Debug, Clone, PartialEq)]
pub struct SimpleType {
    /// `name`.
    pub name: String,
    /// `description`.
    pub description: Option<String>,
    /// The one type element it holds.
    pub kind: SimpleTypeKind,
}

/// The type element of a `SimpleType`.
#[derive(Debug, Clone, PartialEq)]
pub enum SimpleTypeKind {
    /// `Real`.
    Real(RealAttributes),
    /// `Integer`.
    Integer(IntegerAttributes),
    /// `Boolean`.
    Boolean,
    /// `String`.
    String,
    /// `Enumeration` with its items.
    Enumeration {
        /// `quantity`.
        quantity: Option<String>,
        /// `Item`s.
        items: Vec<EnumerationItem>,
    },
}

/// Attributes shared by `Real` in type definitions and in variables.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RealAttributes {
    /// `quantity`.
    pub quantity: Option<String>,
    /// `unit`.
    pub unit: Option<String>,
    /// `displayUnit`.
    pub display_unit: Option<String>,
    /// `relativeQuantity`.
    pub relative_quantity: Option<bool>,
    /// `min`.
    pub min: Option<f64>,
    /// `max`.
    pub max: Option<f64>,
    /// `nominal`.
    pub nominal: Option<f64>,
    /// `unbounded`.
    pub unbounded: Option<bool>,
}

/// Attributes shared by `Integer` in type definitions and in variables.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct IntegerAttributes {
    /// `quantity`.
    pub quantity: Option<String>,
    /// `min`.
    pub min: Option<i32>,
    /// `max`.
    pub max: Option<i32>,
}

/// `Item` of an enumeration type.
#[derive(Debug, Clone, PartialEq)]
pub struct EnumerationItem {
    /// `name`.
    pub name: String,
    /// `value`.
    pub value: i32,
    /// `description`.
    pub description: Option<String>,
}

/// `Category` in `LogCategories`.
#[derive(Debug, Clone, PartialEq)]
pub struct LogCategory {
    /// `name`.
    pub name: String,
    /// `description`.
    pub description: Option<String>,
}

/// `DefaultExperiment`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DefaultExperiment {
    /// `startTime`.
    pub start_time: Option<f64>,
    /// `stopTime`.
    pub stop_time: Option<f64>,
    /// `tolerance`.
    pub tolerance: Option<f64>,
    /// `stepSize`.
    pub step_size: Option<f64>,
}

/// `Tool` element of `VendorAnnotations` or of a variable's `Annotations`.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolAnnotation {
    /// `name` of the tool.
    pub name: String,
    /// The element's inner XML, kept verbatim (the schema allows any content).
    pub content: String,
}

/// `ScalarVariable`.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarVariable {
    /// `name`.
    pub name: String,
    /// `valueReference`.
    pub value_reference: u32,
    /// `description`.
    pub description: Option<String>,
    /// `causality` (absent means `local`).
    pub causality: Option<Causality>,
    /// `variability` (absent means `continuous`).
    pub variability: Option<Variability>,
    /// `initial` (absent means the schema's default for the causality/variability pair).
    pub initial: Option<Initial>,
    /// `canHandleMultipleSetPerTimeInstant`.
    pub can_handle_multiple_set_per_time_instant: Option<bool>,
    /// The type element and its attributes.
    pub kind: VariableKind,
    /// `Annotations/Tool`.
    pub annotations: Vec<ToolAnnotation>,
}

/// The type element of a `ScalarVariable`.
#[derive(Debug, Clone, PartialEq)]
pub enum VariableKind {
    /// `Real`.
    Real {
        /// `declaredType`.
        declared_type: Option<String>,
        /// Unit, bounds and the rest.
        attributes: RealAttributes,
        /// `start`.
        start: Option<f64>,
        /// `derivative`: 1-based index of the state this is the derivative of.
        derivative: Option<u32>,
        /// `reinit`.
        reinit: Option<bool>,
    },
    /// `Integer`.
    Integer {
        /// `declaredType`.
        declared_type: Option<String>,
        /// Bounds.
        attributes: IntegerAttributes,
        /// `start`.
        start: Option<i32>,
    },
    /// `Boolean`.
    Boolean {
        /// `declaredType`.
        declared_type: Option<String>,
        /// `start`.
        start: Option<bool>,
    },
    /// `String`.
    String {
        /// `declaredType`.
        declared_type: Option<String>,
        /// `start`.
        start: Option<String>,
    },
    /// `Enumeration`.
    Enumeration {
        /// `declaredType` (required for enumerations).
        declared_type: String,
        /// `quantity`.
        quantity: Option<String>,
        /// `min`.
        min: Option<i32>,
        /// `max`.
        max: Option<i32>,
        /// `start`.
        start: Option<i32>,
    },
}

/// `causality`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Causality {
    /// `parameter`.
    Parameter,
    /// `calculatedParameter`.
    CalculatedParameter,
    /// `input`.
    Input,
    /// `output`.
    Output,
    /// `local`.
    Local,
    /// `independent`.
    Independent,
}

/// `variability`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Variability {
    /// `constant`.
    Constant,
    /// `fixed`.
    Fixed,
    /// `tunable`.
    Tunable,
    /// `discrete`.
    Discrete,
    /// `continuous`.
    Continuous,
}

/// `initial`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Initial {
    /// `exact`.
    Exact,
    /// `approx`.
    Approx,
    /// `calculated`.
    Calculated,
}

/// `ModelStructure`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelStructure {
    /// `Outputs/Unknown`.
    pub outputs: Vec<Unknown>,
    /// `Derivatives/Unknown`.
    pub derivatives: Vec<Unknown>,
    /// `InitialUnknowns/Unknown`.
    pub initial_unknowns: Vec<Unknown>,
}

/// `Unknown`: a variable (by 1-based index) and what it depends on.
#[derive(Debug, Clone, PartialEq)]
pub struct Unknown {
    /// `index`: 1-based position in `ModelVariables`.
    pub index: u32,
    /// `dependencies`: `None` means "depends on everything" (attribute absent);
    /// `Some(vec![])` means "depends on nothing" (attribute present and empty).
    pub dependencies: Option<Vec<u32>>,
    /// `dependenciesKind`, one per dependency when present.
    pub dependencies_kind: Option<Vec<DependencyKind>>,
}

/// One entry of `dependenciesKind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DependencyKind {
    /// `dependent`.
    Dependent,
    /// `constant`.
    Constant,
    /// `fixed`.
    Fixed,
    /// `tunable`.
    Tunable,
    /// `discrete`.
    Discrete,
}
