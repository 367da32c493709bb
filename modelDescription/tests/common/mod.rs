//! Fixtures shared by the integration tests.
#![allow(dead_code)]

use model_description::*;

pub mod plain_writer;

pub fn real(
    name: &str,
    vr: u32,
    causality: Option<Causality>,
    variability: Option<Variability>,
    initial: Option<Initial>,
    start: Option<f64>,
) -> ScalarVariable {
    ScalarVariable {
        name: name.to_owned(),
        value_reference: vr,
        description: None,
        causality,
        variability,
        initial,
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::Real {
            declared_type: None,
            attributes: RealAttributes::default(),
            start,
            derivative: None,
            reinit: None,
        },
        annotations: Vec::new(),
    }
}

pub fn unknown(index: u32, deps: Option<Vec<u32>>) -> Unknown {
    Unknown {
        index,
        dependencies: deps,
        dependencies_kind: None,
    }
}

/// A description that sets every element and every attribute the types model, and that is
/// semantically valid (`check()` finds nothing).
///
/// Variables (1-based): 1 time, 2 x (state), 3 der(x), 4 u, 5 y, 6 k, 7 k2, 8 n, 9 flag,
/// 10 label, 11 mode, 12 yAlias (alias of y), 13 c.
pub fn full() -> ModelDescription {
    use Causality as C;
    use Variability as V;
    let mut md = ModelDescription::new("Knee & <Bench>", "{8c4e810f-3df3-4a00-8276-176fa3c9f000}");
    md.description = Some("All \"quotes\" & 'apostrophes'\nsecond line\ttab".into());
    md.author = Some("The kneebench developers".into());
    md.version = Some("1.0.0".into());
    md.copyright = Some("© 2025".into());
    md.license = Some("MIT OR Apache-2.0".into());
    md.generation_tool = Some("kneebench 0.1.0".into());
    md.generation_date_and_time = Some("2025-01-01T00:00:00Z".into());
    md.variable_naming_convention = Some(VariableNamingConvention::Structured);
    md.number_of_event_indicators = Some(0);
    md.model_exchange = Some(ModelExchange {
        model_identifier: "knee_me".into(),
        needs_execution_tool: Some(false),
        completed_integrator_step_not_needed: Some(true),
        can_be_instantiated_only_once_per_process: Some(false),
        can_not_use_memory_management_functions: Some(true),
        can_get_and_set_fmu_state: Some(true),
        can_serialize_fmu_state: Some(true),
        provides_directional_derivative: Some(false),
        source_files: vec!["a.c".into(), "b.c".into()],
    });
    md.co_simulation = Some(CoSimulation {
        model_identifier: "knee_cs".into(),
        needs_execution_tool: Some(false),
        can_handle_variable_communication_step_size: Some(true),
        can_interpolate_inputs: Some(false),
        max_output_derivative_order: Some(1),
        can_run_asynchronuously: Some(false),
        can_be_instantiated_only_once_per_process: Some(false),
        can_not_use_memory_management_functions: Some(true),
        can_get_and_set_fmu_state: Some(true),
        can_serialize_fmu_state: Some(true),
        provides_directional_derivative: Some(false),
        source_files: vec!["c.c".into()],
    });
    md.unit_definitions = vec![
        Unit {
            name: "rad".into(),
            base_unit: Some(BaseUnit {
                kg: Some(0),
                m: Some(0),
                s: Some(0),
                a: Some(0),
                k: Some(0),
                mol: Some(0),
                cd: Some(0),
                rad: Some(1),
                factor: Some(1.0),
                offset: Some(0.0),
            }),
            display_units: vec![DisplayUnit {
                name: "deg".into(),
                factor: Some(57.29577951308232),
                offset: Some(0.0),
            }],
        },
        Unit {
            name: "N.m".into(),
            base_unit: Some(BaseUnit {
                kg: Some(1),
                m: Some(2),
                s: Some(-2),
                ..BaseUnit::default()
            }),
            display_units: vec![DisplayUnit {
                name: "kN.m".into(),
                factor: Some(1e-3),
                offset: None,
            }],
        },
        Unit {
            name: "1".into(),
            base_unit: None,
            display_units: Vec::new(),
        },
    ];
    md.type_definitions = vec![
        SimpleType {
            name: "Angle".into(),
            description: Some("joint angle".into()),
            kind: SimpleTypeKind::Real(RealAttributes {
                quantity: Some("Angle".into()),
                unit: Some("rad".into()),
                display_unit: Some("deg".into()),
                relative_quantity: Some(false),
                min: Some(-10.0),
                max: Some(10.0),
                nominal: Some(1.0),
                unbounded: Some(true),
            }),
        },
        SimpleType {
            name: "Count".into(),
            description: None,
            kind: SimpleTypeKind::Integer(IntegerAttributes {
                quantity: Some("Count".into()),
                min: Some(0),
                max: Some(100),
            }),
        },
        SimpleType {
            name: "Flag".into(),
            description: None,
            kind: SimpleTypeKind::Boolean,
        },
        SimpleType {
            name: "Text".into(),
            description: None,
            kind: SimpleTypeKind::String,
        },
        SimpleType {
            name: "Mode".into(),
            description: Some("operating mode".into()),
            kind: SimpleTypeKind::Enumeration {
                quantity: Some("Mode".into()),
                items: vec![
                    EnumerationItem {
                        name: "Off".into(),
                        value: 1,
                        description: None,
                    },
                    EnumerationItem {
                        name: "On".into(),
                        value: 2,
                        description: Some("running".into()),
                    },
                    EnumerationItem {
                        name: "Fault".into(),
                        value: 3,
                        description: None,
                    },
                ],
            },
        },
    ];
    md.log_categories = vec![
        LogCategory {
            name: "logEvents".into(),
            description: Some("events".into()),
        },
        LogCategory {
            name: "logStatusError".into(),
            description: None,
        },
    ];
    md.default_experiment = Some(DefaultExperiment {
        start_time: Some(0.0),
        stop_time: Some(10.0),
        tolerance: Some(1e-6),
        step_size: Some(0.001),
    });
    md.vendor_annotations = vec![
        ToolAnnotation {
            name: "kneebench".into(),
            content: "<Bench id=\"1\"><Sensor name=\"enc &amp; tacho\"/><!-- c --></Bench>".into(),
        },
        ToolAnnotation {
            name: "empty".into(),
            content: String::new(),
        },
    ];

    let mut time = real(
        "time",
        0,
        Some(C::Independent),
        Some(V::Continuous),
        None,
        None,
    );
    time.description = Some("simulation time".into());
    let mut x = real(
        "x",
        1,
        Some(C::Local),
        Some(V::Continuous),
        Some(Initial::Exact),
        Some(0.1),
    );
    x.description = Some("a & b < c > \"d\" 'e'\n\ttab".into());
    x.can_handle_multiple_set_per_time_instant = Some(true);
    x.kind = VariableKind::Real {
        declared_type: Some("Angle".into()),
        attributes: RealAttributes {
            quantity: Some("Angle".into()),
            unit: Some("rad".into()),
            display_unit: Some("deg".into()),
            relative_quantity: Some(false),
            min: Some(-3.0),
            max: Some(3.0),
            nominal: Some(1.0),
            unbounded: Some(false),
        },
        start: Some(0.1),
        derivative: None,
        reinit: Some(true),
    };
    let mut der_x = real("der(x)", 2, None, None, None, None);
    if let VariableKind::Real { derivative, .. } = &mut der_x.kind {
        *derivative = Some(2);
    }
    let mut u = real("u", 3, Some(C::Input), Some(V::Continuous), None, Some(0.0));
    u.can_handle_multiple_set_per_time_instant = Some(false);
    let y = real(
        "y",
        4,
        Some(C::Output),
        None,
        Some(Initial::Calculated),
        None,
    );
    let k = real(
        "k",
        5,
        Some(C::Parameter),
        Some(V::Fixed),
        Some(Initial::Exact),
        Some(2.5),
    );
    let k2 = real(
        "k2",
        6,
        Some(C::CalculatedParameter),
        Some(V::Fixed),
        None,
        None,
    );
    let n = ScalarVariable {
        name: "n".into(),
        value_reference: 0,
        description: None,
        causality: Some(C::Parameter),
        variability: Some(V::Tunable),
        initial: None,
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::Integer {
            declared_type: Some("Count".into()),
            attributes: IntegerAttributes {
                quantity: Some("Count".into()),
                min: Some(0),
                max: Some(10),
            },
            start: Some(3),
        },
        annotations: Vec::new(),
    };
    let flag = ScalarVariable {
        name: "flag".into(),
        value_reference: 0,
        description: None,
        causality: Some(C::Input),
        variability: Some(V::Discrete),
        initial: None,
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::Boolean {
            declared_type: Some("Flag".into()),
            start: Some(true),
        },
        annotations: Vec::new(),
    };
    let label = ScalarVariable {
        name: "label".into(),
        value_reference: 0,
        description: None,
        causality: Some(C::Parameter),
        variability: Some(V::Fixed),
        initial: Some(Initial::Exact),
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::String {
            declared_type: Some("Text".into()),
            start: Some("a<b & 'c' \"d\"".into()),
        },
        annotations: Vec::new(),
    };
    let mode = ScalarVariable {
        name: "mode".into(),
        value_reference: 1,
        description: Some("mode".into()),
        causality: Some(C::Output),
        variability: Some(V::Discrete),
        initial: Some(Initial::Exact),
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::Enumeration {
            declared_type: "Mode".into(),
            quantity: Some("Mode".into()),
            min: Some(1),
            max: Some(3),
            start: Some(2),
        },
        annotations: vec![ToolAnnotation {
            name: "kneebench".into(),
            content: "\n        <Display widget=\"led\"/>\n      ".into(),
        }],
    };
    let y_alias = real(
        "yAlias",
        4,
        Some(C::Output),
        Some(V::Continuous),
        None,
        None,
    );
    let c = real("c", 7, Some(C::Local), Some(V::Constant), None, Some(1e-5));
    md.model_variables = vec![
        time, x, der_x, u, y, k, k2, n, flag, label, mode, y_alias, c,
    ];

    md.model_structure = ModelStructure {
        outputs: vec![
            Unknown {
                index: 5,
                dependencies: Some(vec![2, 4]),
                dependencies_kind: Some(vec![DependencyKind::Dependent, DependencyKind::Constant]),
            },
            unknown(11, Some(vec![])),
            Unknown {
                index: 12,
                dependencies: Some(vec![]),
                dependencies_kind: Some(vec![]),
            },
        ],
        derivatives: vec![Unknown {
            index: 3,
            dependencies: Some(vec![2, 4]),
            dependencies_kind: Some(vec![DependencyKind::Fixed, DependencyKind::Tunable]),
        }],
        initial_unknowns: vec![
            Unknown {
                index: 3,
                dependencies: Some(vec![2, 4, 6]),
                dependencies_kind: Some(vec![
                    DependencyKind::Dependent,
                    DependencyKind::Discrete,
                    DependencyKind::Dependent,
                ]),
            },
            unknown(5, None),
            unknown(7, Some(vec![6])),
            unknown(12, None),
        ],
    };
    md
}

/// A third-party description in the style of Dymola / OpenModelica output: model exchange and
/// co-simulation, namespace attributes, unknown attributes, comments, a processing
/// instruction, vendor annotations with nested elements, an enumeration type.
pub const THIRD_PARTY: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<!-- generated by a Modelica tool -->
<?some-tool processing instruction?>
<fmiModelDescription
  xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
  fmiVersion="2.0"
  modelName="Knee.Plant"
  guid="{1a2b3c4d-0000-1111-2222-333344445555}"
  description="Knee plant &amp; actuator"
  generationTool="Dymola Version 2024x"
  generationDateAndTime="2024-05-06T07:08:09Z"
  variableNamingConvention="structured"
  numberOfEventIndicators="2"
  xsi:noNamespaceSchemaLocation="fmi2ModelDescription.xsd"
  vendorExtension="ignored">
  <ModelExchange
    modelIdentifier="Knee_Plant"
    canGetAndSetFMUstate="true"
    canSerializeFMUstate="1"
    providesDirectionalDerivative="0">
    <SourceFiles>
      <File name="all.c"/>
    </SourceFiles>
  </ModelExchange>
  <CoSimulation
    modelIdentifier="Knee_Plant"
    canHandleVariableCommunicationStepSize="true"
    canInterpolateInputs="true"
    maxOutputDerivativeOrder="1"
    canGetAndSetFMUstate="true"
    canSerializeFMUstate="true"
    providesDirectionalDerivative="false"
    someFutureFlag="true"/>
  <UnitDefinitions>
    <Unit name="rad">
      <BaseUnit rad="1"/>
      <DisplayUnit name="deg" factor="57.2957795130823"/>
    </Unit>
    <Unit name="rad/s">
      <BaseUnit s="-1" rad="1"/>
    </Unit>
    <Unit name="N.m">
      <BaseUnit kg="1" m="2" s="-2"/>
    </Unit>
  </UnitDefinitions>
  <TypeDefinitions>
    <SimpleType name="Modelica.SIunits.Angle">
      <Real quantity="Angle" unit="rad" displayUnit="deg"/>
    </SimpleType>
    <SimpleType name="Modelica.SIunits.AngularVelocity">
      <Real quantity="AngularVelocity" unit="rad/s"/>
    </SimpleType>
    <SimpleType name="Knee.Mode">
      <Enumeration>
        <Item name="idle" value="1" description="not moving"/>
        <Item name="track" value="2"/>
        <Item name="trip" value="3" description="safety trip"/>
      </Enumeration>
    </SimpleType>
  </TypeDefinitions>
  <LogCategories>
    <Category name="logEvents" description="Log events"/>
    <Category name="logStatusWarning"/>
  </LogCategories>
  <DefaultExperiment startTime="0.0" stopTime="2.0" tolerance="1E-06" stepSize="1e-3"/>
  <VendorAnnotations>
    <Tool name="Dymola">
      <Settings>
        <Setting name="Advanced.Define.DAEsolver" value="false"/>
        <!-- nested comment -->
        <Group><Inner a='1'>text &amp; more</Inner></Group>
      </Settings>
    </Tool>
    <Tool name="OpenModelica"/>
  </VendorAnnotations>
  <ModelVariables>
    <!-- Index = 1 -->
    <ScalarVariable
      name="phi"
      valueReference="33554432"
      description="joint angle"
      causality="output"
      variability="continuous"
      initial="exact"
      hideResult="false">
      <Real
        declaredType="Modelica.SIunits.Angle"
        start="0.1"/>
      <Annotations>
        <Tool name="Dymola"><Hidden value="false"/></Tool>
      </Annotations>
    </ScalarVariable>
    <!-- Index = 2 -->
    <ScalarVariable
      name="der(phi)"
      valueReference="587202560"
      causality="output"
      variability="continuous">
      <Real
        declaredType="Modelica.SIunits.AngularVelocity"
        derivative="1"/>
    </ScalarVariable>
    <!-- Index = 3 -->
    <ScalarVariable
      name="tau"
      valueReference="352321536"
      description="motor torque"
      causality="input"
      variability="continuous">
      <Real unit="N.m" min="-100" max="100" start="0"/>
    </ScalarVariable>
    <!-- Index = 4 -->
    <ScalarVariable
      name="inertia"
      valueReference="16777216"
      causality="parameter"
      variability="fixed">
      <Real start="0.05" min="0.0" nominal="0.1" unit="N.m"/>
    </ScalarVariable>
    <!-- Index = 5 -->
    <ScalarVariable
      name="mode"
      valueReference="33554433"
      causality="output"
      variability="discrete">
      <Enumeration declaredType="Knee.Mode"/>
    </ScalarVariable>
    <!-- Index = 6 -->
    <ScalarVariable
      name="enabled"
      valueReference="16777217"
      causality="parameter"
      variability="tunable">
      <Boolean start="true"/>
    </ScalarVariable>
    <!-- Index = 7 -->
    <ScalarVariable
      name="steps"
      valueReference="16777218"
      variability="discrete">
      <Integer/>
    </ScalarVariable>
    <!-- Index = 8 -->
    <ScalarVariable
      name="name"
      valueReference="16777219"
      causality="parameter"
      variability="fixed">
      <String start="left knee"/>
    </ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="1" dependencies="" dependenciesKind=""/>
      <Unknown index="2" dependencies="1 3" dependenciesKind="dependent dependent"/>
      <Unknown index="5" dependencies=""/>
    </Outputs>
    <Derivatives>
      <Unknown index="2" dependencies="1 3"/>
    </Derivatives>
    <InitialUnknowns>
      <Unknown index="2" dependencies="1 3 4" dependenciesKind="dependent dependent dependent"/>
      <Unknown index="5"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"#;
