//! The node's parameter services, served here as an rclcpp node serves them (ros2-client 0.12's
//! own services answer `describe_parameters` with a placeholder and `read_only: false`):
//! `~/list_parameters`, `~/get_parameters`, `~/get_parameter_types`, `~/describe_parameters`
//! (our table's description, type, range and read_only), `~/set_parameters` and
//! `~/set_parameters_atomically` (checked and applied by [`LiveParams`]), with a
//! `/parameter_events` message for every accepted change.
//!
//! [`Answers`] computes the responses (no DDS; unit-tested); `ParamServices` serves them on
//! ros2-client's service API.

use std::sync::Arc;

use futures::StreamExt;
use ros2_client::parameters::raw;
use ros2_client::parameters::{Parameter, ParameterValue as RosValue};
use ros2_client::qos::{History, WhenFull};
use ros2_client::rcl_interfaces::{
    DescribeParametersRequest, DescribeParametersResponse, GetParameterTypesRequest,
    GetParameterTypesResponse, GetParametersRequest, GetParametersResponse, ListParametersRequest,
    ListParametersResponse, ListParametersResult, SetParametersAtomicallyResponse,
    SetParametersRequest, SetParametersResponse,
};
use ros2_client::service::Server;
use ros2_client::{
    MessageTypeName, Name, Node, Publisher, QosProfile, ServiceMapping, ServiceTypeName,
};

use super::clock;
use super::log::{log_info, node_log};
use super::params::{to_ros, LiveParams, SetError};
use super::NodeError;
use crate::params::set::USE_SIM_TIME;
use crate::params::{param_spec, ParamError, ParamRange, ParamSet, ParamSpec};
use crate::ros::param_value::ParamKind;

/// rcl_interfaces/ParameterType codes.
fn type_code(kind: ParamKind) -> u8 {
    match kind {
        ParamKind::Bool => 1,
        ParamKind::Int => 2,
        ParamKind::Double => 3,
        ParamKind::String => 4,
        ParamKind::BoolArray => 6,
        ParamKind::IntArray => 7,
        ParamKind::DoubleArray => 8,
        ParamKind::StringArray => 9,
    }
}

/// The rcl_interfaces/ParameterDescriptor of a parameter of the table, as rclcpp answers for
/// a parameter declared with it: integer ranges with step 1 (every integer), floating-point
/// ranges with step 0 (continuous; an unbounded side as +-f64::MAX, as rclcpp users write
/// it), what a range cannot say (exclusive bounds, a set of strings, names) in
/// `additional_constraints`.
pub fn descriptor(spec: &ParamSpec) -> raw::ParameterDescriptor {
    let mut integer_range = Vec::new();
    let mut floating_point_range = Vec::new();
    let mut constraints = String::new();
    match &spec.range {
        ParamRange::Any => {}
        ParamRange::Int { min, max } => integer_range.push(raw::IntegerRange {
            from_value: *min,
            to_value: *max,
            step: 1,
        }),
        ParamRange::Double {
            min,
            max,
            min_exclusive,
            max_exclusive,
        } => {
            let finite = |v: f64| {
                if v.is_finite() {
                    v
                } else {
                    v.signum() * f64::MAX
                }
            };
            floating_point_range.push(raw::FloatingPointRange {
                from_value: finite(*min),
                to_value: finite(*max),
                step: 0.0,
            });
            if *min_exclusive || *max_exclusive {
                constraints = spec.range.describe();
            }
        }
        other => constraints = other.describe(),
    }
    raw::ParameterDescriptor {
        name: spec.name.to_string(),
        r#type: type_code(spec.kind),
        description: spec.description.to_string(),
        additional_constraints: constraints,
        read_only: spec.read_only,
        dynamic_typing: false,
        floating_point_range,
        integer_range,
    }
}

/// `use_sim_time`, which every rcl node has ([`super::clock`]).
fn use_sim_time_descriptor() -> raw::ParameterDescriptor {
    raw::ParameterDescriptor {
        name: USE_SIM_TIME.into(),
        r#type: 1,
        description: "The node's time from /clock (rosgraph_msgs/Clock) instead of the system \
                      clock: the stamps of /diagnostics, /rosout and /parameter_events, and \
                      the latency in /diagnostics. Depth, the other outputs and the mesh keep \
                      their input images' stamps either way."
            .into(),
        additional_constraints: String::new(),
        read_only: false,
        dynamic_typing: false,
        floating_point_range: Vec::new(),
        integer_range: Vec::new(),
    }
}

/// The parameters a node serves.
enum Table {
    /// The depth node's: every parameter of the table, changed as [`LiveParams`] checks.
    Live(Arc<LiveParams>),
    /// The `fuse` node's: `names` only, with their values at start, all read-only.
    Fixed {
        params: ParamSet,
        names: &'static [&'static str],
    },
}

impl Table {
    fn names(&self) -> Vec<String> {
        match self {
            Table::Live(live) => live
                .params()
                .iter()
                .map(|(spec, _)| spec.name.to_string())
                .collect(),
            Table::Fixed { names, .. } => names.iter().map(|n| n.to_string()).collect(),
        }
    }

    /// The spec of a parameter the node serves (not `use_sim_time`).
    fn spec(&self, name: &str) -> Option<&'static ParamSpec> {
        match self {
            Table::Live(_) => param_spec(name),
            Table::Fixed { names, .. } => names.contains(&name).then(|| param_spec(name))?,
        }
    }

    fn value(&self, name: &str) -> Option<RosValue> {
        match self {
            Table::Live(live) => live.params().get(name).map(to_ros),
            Table::Fixed { params, .. } => self.spec(name).and(params.get(name)).map(to_ros),
        }
    }

    fn describe(&self, spec: &ParamSpec) -> raw::ParameterDescriptor {
        raw::ParameterDescriptor {
            read_only: spec.read_only || matches!(self, Table::Fixed { .. }),
            ..descriptor(spec)
        }
    }

    /// Checks `changes` together and stores them, all or none; per change, whether it changed
    /// the value. A fixed table takes only a parameter's own value again (as a read-only one of
    /// the live table).
    fn apply_all(&self, changes: &[(String, RosValue)]) -> Result<Vec<bool>, SetError> {
        match self {
            Table::Live(live) => live.apply_all(changes),
            Table::Fixed { .. } => changes
                .iter()
                .map(|(name, value)| match self.value(name) {
                    None => Err(ParamError::Unknown(name.clone()).into()),
                    Some(current) if current == *value => Ok(false),
                    Some(_) => Err(ParamError::ReadOnly(name.clone()).into()),
                })
                .collect(),
        }
    }
}

/// The answers of the six services over the node's parameters.
pub struct Answers {
    table: Table,
}

impl Answers {
    /// The depth node's: every parameter of the table, live.
    pub fn new(live: Arc<LiveParams>) -> Self {
        Self {
            table: Table::Live(live),
        }
    }

    /// A node whose parameters are fixed at start (the `fuse` node): `names` of `params`,
    /// read-only; `use_sim_time` still switches.
    pub fn fixed(params: ParamSet, names: &'static [&'static str]) -> Self {
        Self {
            table: Table::Fixed { params, names },
        }
    }

    /// Every name, `use_sim_time` included, sorted (our names have no `.`: no prefixes).
    pub fn list(&self, req: &ListParametersRequest) -> ListParametersResult {
        let mut names: Vec<String> = self
            .table
            .names()
            .into_iter()
            .chain([USE_SIM_TIME.to_string()])
            .filter(|name| {
                req.prefixes.is_empty()
                    || req
                        .prefixes
                        .iter()
                        .any(|p| name == p || name.starts_with(&format!("{p}.")))
            })
            .collect();
        names.sort();
        ListParametersResult {
            names,
            prefixes: Vec::new(),
        }
    }

    fn value(&self, name: &str) -> RosValue {
        if name == USE_SIM_TIME {
            return RosValue::Boolean(clock::uses_sim_time());
        }
        self.table.value(name).unwrap_or(RosValue::NotSet)
    }

    /// The values (NOT_SET for an unknown name, as ros2-client answered before).
    pub fn get(&self, req: &GetParametersRequest) -> GetParametersResponse {
        GetParametersResponse {
            values: req
                .names
                .iter()
                .map(|n| raw::ParameterValue::from(self.value(n)))
                .collect(),
        }
    }

    /// The type codes (0, NOT_SET, for an unknown name).
    pub fn types(&self, req: &GetParameterTypesRequest) -> GetParameterTypesResponse {
        GetParameterTypesResponse {
            values: req
                .names
                .iter()
                .map(|n| match (n.as_str(), self.table.spec(n)) {
                    (USE_SIM_TIME, _) => 1,
                    (_, Some(spec)) => type_code(spec.kind),
                    (_, None) => 0,
                })
                .collect(),
        }
    }

    /// The descriptors (an unknown name: type NOT_SET, read-only, "not declared").
    pub fn describe(&self, req: &DescribeParametersRequest) -> DescribeParametersResponse {
        DescribeParametersResponse {
            values: req
                .names
                .iter()
                .map(|n| match (n.as_str(), self.table.spec(n)) {
                    (USE_SIM_TIME, _) => use_sim_time_descriptor(),
                    (_, Some(spec)) => self.table.describe(spec),
                    (_, None) => raw::ParameterDescriptor {
                        name: n.clone(),
                        r#type: 0,
                        description: "parameter not declared".into(),
                        additional_constraints: String::new(),
                        read_only: true,
                        dynamic_typing: false,
                        floating_point_range: Vec::new(),
                        integer_range: Vec::new(),
                    },
                })
                .collect(),
        }
    }

    /// Sets one parameter; returns the result and, when the value changed, the parameter for
    /// `/parameter_events`.
    fn set_one(&self, p: Parameter) -> (raw::SetParametersResult, Option<raw::Parameter>) {
        let refused = |reason: String| raw::SetParametersResult {
            successful: false,
            reason,
        };
        if p.name == USE_SIM_TIME {
            return match p.value {
                RosValue::Boolean(on) => (ok(), set_use_sim_time(on)),
                ref other => (refused(not_a_bool(other)), None),
            };
        }
        match self.table.apply_all(&[(p.name.clone(), p.value.clone())]) {
            Ok(changed) => {
                let changed = changed.contains(&true);
                if changed {
                    log_info(&format!(
                        "parameter '{}' set to {:?} (used from the next frame set on)",
                        p.name, p.value
                    ));
                }
                // The value as stored (an integer given for a double is kept as the double),
                // as `get_parameters` answers it.
                let event = changed.then(|| {
                    raw::Parameter::from(Parameter {
                        value: self.value(&p.name),
                        name: p.name.clone(),
                    })
                });
                (ok(), event)
            }
            Err(e) => {
                node_log(
                    tracing::Level::WARN,
                    &format!(
                        "rejected setting parameter '{}' to {:?}: {e}",
                        p.name, p.value
                    ),
                );
                (refused(e.to_string()), None)
            }
        }
    }

    /// Each parameter on its own, in order.
    pub fn set(&self, req: SetParametersRequest) -> (SetParametersResponse, Vec<raw::Parameter>) {
        let mut events = Vec::new();
        let results = req
            .parameter
            .into_iter()
            .map(|p| {
                let (result, event) = self.set_one(Parameter::from(p));
                events.extend(event);
                result
            })
            .collect();
        (SetParametersResponse { results }, events)
    }

    /// All or none: every parameter is checked on the values the earlier ones give, then all
    /// are applied.
    pub fn set_atomically(
        &self,
        req: SetParametersRequest,
    ) -> (SetParametersAtomicallyResponse, Vec<raw::Parameter>) {
        let params: Vec<Parameter> = req.parameter.into_iter().map(Parameter::from).collect();
        let mut sim_time = None;
        for p in params.iter().filter(|p| p.name == USE_SIM_TIME) {
            match p.value {
                RosValue::Boolean(on) => sim_time = Some(on),
                ref other => {
                    let result = raw::SetParametersResult {
                        successful: false,
                        reason: not_a_bool(other),
                    };
                    return (SetParametersAtomicallyResponse { result }, Vec::new());
                }
            }
        }
        let ours: Vec<(String, RosValue)> = params
            .into_iter()
            .filter(|p| p.name != USE_SIM_TIME)
            .map(|p| (p.name, p.value))
            .collect();
        match self.table.apply_all(&ours) {
            Ok(changed) => {
                let sim_time_event = sim_time.and_then(set_use_sim_time);
                let events = ours
                    .into_iter()
                    .zip(changed)
                    .filter(|(_, c)| *c)
                    .map(|((name, _), _)| {
                        let value = self.value(&name);
                        raw::Parameter::from(Parameter { name, value })
                    })
                    .chain(sim_time_event)
                    .collect();
                (SetParametersAtomicallyResponse { result: ok() }, events)
            }
            Err(e) => {
                let result = raw::SetParametersResult {
                    successful: false,
                    reason: e.to_string(),
                };
                (SetParametersAtomicallyResponse { result }, Vec::new())
            }
        }
    }
}

/// Switches the node's clock; the `/parameter_events` entry when it changed.
fn set_use_sim_time(on: bool) -> Option<raw::Parameter> {
    clock::set_use_sim_time(on).then(|| {
        log_info(&format!(
            "parameter 'use_sim_time' set to {on}: the node's time is {}",
            if on { "/clock's" } else { "the system clock's" }
        ));
        raw::Parameter::from(Parameter {
            name: USE_SIM_TIME.into(),
            value: RosValue::Boolean(on),
        })
    })
}

fn not_a_bool(value: &RosValue) -> String {
    format!("use_sim_time takes a bool, not {value:?}")
}

fn ok() -> raw::SetParametersResult {
    raw::SetParametersResult {
        successful: true,
        reason: String::new(),
    }
}

/// A node's `/parameter_events` writer, with rcl's QoS (`rmw_qos_profile_parameter_events`:
/// reliable, volatile, keep last 1000).
pub(super) fn parameter_events_writer(
    node: &mut Node,
) -> Result<Publisher<raw::ParameterEvent>, NodeError> {
    let qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 1000 });
    let topic = node
        .create_topic(
            &Name::new("/", "parameter_events").map_err(ros_err)?,
            MessageTypeName::new("rcl_interfaces", "ParameterEvent"),
            &qos,
        )
        .map_err(ros_err)?;
    node.create_publisher(&topic, Some(qos)).map_err(ros_err)
}

/// The six servers and the `/parameter_events` writer of one node.
pub(super) struct ParamServices {
    answers: Answers,
    node_fqn: String,
    list: Server<ListParametersRequest, ListParametersResponse>,
    get: Server<GetParametersRequest, GetParametersResponse>,
    types: Server<GetParameterTypesRequest, GetParameterTypesResponse>,
    describe: Server<DescribeParametersRequest, DescribeParametersResponse>,
    set: Server<SetParametersRequest, SetParametersResponse>,
    set_atomically: Server<SetParametersRequest, SetParametersAtomicallyResponse>,
    events: Publisher<raw::ParameterEvent>,
}

fn ros_err(e: impl std::fmt::Debug) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
}

impl ParamServices {
    /// The servers under the node's name (`<fqn>/describe_parameters`, ...), with rclcpp's
    /// service QoS (reliable, keep last 10), and the `/parameter_events` writer.
    pub fn new(node: &mut Node, node_fqn: &str, answers: Answers) -> Result<Self, NodeError> {
        let qos = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .history(History::KeepLast { depth: 10 });
        let name = |service: &str| {
            Name::new(node_fqn, service).map_err(|e| NodeError::Name {
                name: format!("{node_fqn}/{service}"),
                reason: format!("{e:?}"),
            })
        };
        macro_rules! server {
            ($service:literal, $type:literal) => {
                node.create_server(
                    ServiceMapping::Enhanced,
                    &name($service)?,
                    &ServiceTypeName::new("rcl_interfaces", $type),
                    qos.clone(),
                    qos.clone(),
                )
                .map_err(ros_err)?
            };
        }
        let list = server!("list_parameters", "ListParameters");
        let get = server!("get_parameters", "GetParameters");
        let types = server!("get_parameter_types", "GetParameterTypes");
        let describe = server!("describe_parameters", "DescribeParameters");
        let set = server!("set_parameters", "SetParameters");
        let set_atomically = server!("set_parameters_atomically", "SetParametersAtomically");
        let events = parameter_events_writer(node)?;
        Ok(Self {
            answers,
            node_fqn: node_fqn.to_string(),
            list,
            get,
            types,
            describe,
            set,
            set_atomically,
            events,
        })
    }

    fn publish_changes(&self, changed: Vec<raw::Parameter>) {
        if changed.is_empty() {
            return;
        }
        let event = raw::ParameterEvent {
            stamp: ros2_client::builtin_interfaces::Time::from_nanos(clock::now().to_nanos()),
            node: self.node_fqn.clone(),
            new_parameters: Vec::new(),
            changed_parameters: changed,
            deleted_parameters: Vec::new(),
        };
        if let Err(e) = self.events.publish(event) {
            tracing::warn!("/parameter_events: {e:?}");
        }
    }

    /// Answers requests until a request stream fails.
    pub async fn serve(&self) -> NodeError {
        let mut list = self.list.receive_request_stream();
        let mut get = self.get.receive_request_stream();
        let mut types = self.types.receive_request_stream();
        let mut describe = self.describe.receive_request_stream();
        let mut set = self.set.receive_request_stream();
        let mut set_atomically = self.set_atomically.receive_request_stream();
        loop {
            let sent = futures::select! {
                r = list.select_next_some() => match r {
                    Ok((id, req)) => {
                        let result = self.answers.list(&req);
                        self.list.async_send_response(id, ListParametersResponse { result }).await
                    }
                    Err(e) => return ros_err(e),
                },
                r = get.select_next_some() => match r {
                    Ok((id, req)) => self.get.async_send_response(id, self.answers.get(&req)).await,
                    Err(e) => return ros_err(e),
                },
                r = types.select_next_some() => match r {
                    Ok((id, req)) => {
                        self.types.async_send_response(id, self.answers.types(&req)).await
                    }
                    Err(e) => return ros_err(e),
                },
                r = describe.select_next_some() => match r {
                    Ok((id, req)) => {
                        self.describe.async_send_response(id, self.answers.describe(&req)).await
                    }
                    Err(e) => return ros_err(e),
                },
                r = set.select_next_some() => match r {
                    Ok((id, req)) => {
                        let (response, changed) = self.answers.set(req);
                        self.publish_changes(changed);
                        self.set.async_send_response(id, response).await
                    }
                    Err(e) => return ros_err(e),
                },
                r = set_atomically.select_next_some() => match r {
                    Ok((id, req)) => {
                        let (response, changed) = self.answers.set_atomically(req);
                        self.publish_changes(changed);
                        self.set_atomically.async_send_response(id, response).await
                    }
                    Err(e) => return ros_err(e),
                },
            };
            if let Err(e) = sent {
                tracing::warn!("parameter service response: {e:?}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::{ParamSet, ParamValue};
    use crate::sweep::SweepParams;

    fn answers() -> Answers {
        let mut set = ParamSet::defaults();
        set.set(
            "cameras",
            &ParamValue::StringArray(vec!["a".into(), "b".into()]),
        )
        .unwrap();
        let mut sweep = SweepParams::default();
        crate::params::apply_to_sweep(&set, &mut sweep).unwrap();
        Answers::new(LiveParams::new(
            set,
            sweep,
            crate::sweep::RigShape::chosen_views(2, true),
        ))
    }

    fn describe(a: &Answers, name: &str) -> raw::ParameterDescriptor {
        a.describe(&DescribeParametersRequest {
            names: vec![name.into()],
        })
        .values
        .remove(0)
    }

    #[test]
    fn descriptors_carry_the_table() {
        let a = answers();
        let d = describe(&a, "num_planes");
        assert_eq!((d.r#type, d.read_only), (2, false));
        assert_eq!(
            (d.integer_range[0].from_value, d.integer_range[0].to_value),
            (2, 4096)
        );
        assert_eq!(d.integer_range[0].step, 1);
        // min_depth > 0: an inclusive range from 0 to the largest double, the exclusive bound
        // said in words.
        let d = describe(&a, "min_depth");
        assert_eq!(d.r#type, 3);
        assert_eq!(d.floating_point_range[0].from_value, 0.0);
        assert_eq!(d.floating_point_range[0].to_value, f64::MAX);
        assert!(d.additional_constraints.contains('>'), "{d:?}");
        let d = describe(&a, "optimizer");
        assert!(d.additional_constraints.contains("sgm"), "{d:?}");
        let d = describe(&a, "cameras");
        assert!(d.read_only && d.r#type == 9 && !d.description.is_empty());
        let d = describe(&a, "nope");
        assert_eq!((d.r#type, d.read_only), (0, true));
        let d = describe(&a, USE_SIM_TIME);
        assert!(!d.read_only && d.r#type == 1 && d.description.contains("/clock"));
        let types = a.types(&GetParameterTypesRequest {
            names: vec![
                "num_planes".into(),
                "cameras".into(),
                "nope".into(),
                USE_SIM_TIME.into(),
            ],
        });
        assert_eq!(types.values, [2, 9, 0, 1]);
    }

    #[test]
    fn list_get_and_sets() {
        let a = answers();
        let all = a.list(&ListParametersRequest {
            prefixes: vec![],
            depth: 0,
        });
        assert_eq!(all.names.len(), crate::params::param_table().len() + 1);
        let some = a.list(&ListParametersRequest {
            prefixes: vec!["num_planes".into()],
            depth: 0,
        });
        assert_eq!(some.names, ["num_planes"]);
        let set = |name: &str, value: RosValue| SetParametersRequest {
            parameter: vec![raw::Parameter::from(Parameter {
                name: name.into(),
                value,
            })],
        };
        let (r, events) = a.set(set("num_planes", RosValue::Integer(32)));
        assert!(r.results[0].successful && events.len() == 1);
        let (r, events) = a.set(set("num_planes", RosValue::Integer(32)));
        assert!(
            r.results[0].successful && events.is_empty(),
            "no change, no event"
        );
        let (r, _) = a.set(set("cameras", RosValue::StringArray(vec!["x".into()])));
        assert!(!r.results[0].successful && r.results[0].reason.contains("read-only"));
        {
            // use_sim_time switches the process's clock: one test at a time.
            let _clock = clock::TEST_SERIAL.lock().unwrap_or_else(|e| e.into_inner());
            let get = |name: &str| {
                let got = a.get(&GetParametersRequest {
                    names: vec![name.into()],
                });
                RosValue::from(got.values[0].clone())
            };
            clock::set_use_sim_time(false);
            let (r, events) = a.set(set(USE_SIM_TIME, RosValue::Boolean(true)));
            assert!(r.results[0].successful && events.len() == 1);
            assert!(clock::uses_sim_time());
            assert_eq!(get(USE_SIM_TIME), RosValue::Boolean(true));
            let (r, events) = a.set(set(USE_SIM_TIME, RosValue::String("yes".into())));
            assert!(!r.results[0].successful && events.is_empty());
            assert!(r.results[0].reason.contains("bool"), "{r:?}");
            // Atomically with an engine parameter: all or none.
            let both = |sim: bool, planes: i64| SetParametersRequest {
                parameter: set(USE_SIM_TIME, RosValue::Boolean(sim))
                    .parameter
                    .into_iter()
                    .chain(set("num_planes", RosValue::Integer(planes)).parameter)
                    .collect(),
            };
            let (r, _) = a.set_atomically(both(false, 1));
            assert!(!r.result.successful && clock::uses_sim_time(), "none");
            let (r, events) = a.set_atomically(both(false, 32));
            assert!(r.result.successful && !clock::uses_sim_time(), "all");
            assert_eq!(events.len(), 1, "num_planes unchanged: {events:?}");
            assert_eq!(get(USE_SIM_TIME), RosValue::Boolean(false));
        }
        let got = a.get(&GetParametersRequest {
            names: vec!["num_planes".into()],
        });
        assert_eq!(RosValue::from(got.values[0].clone()), RosValue::Integer(32));
        let (r, events) = a.set_atomically(SetParametersRequest {
            parameter: set("num_planes", RosValue::Integer(16))
                .parameter
                .into_iter()
                .chain(set("num_planes", RosValue::Integer(1)).parameter)
                .collect(),
        });
        assert!(!r.result.successful && events.is_empty());
        assert_eq!(a.value("num_planes"), RosValue::Integer(32), "all or none");
        // An integer given for a double is stored as the double, and the event says what is
        // stored (as `get_parameters` answers), alone and atomically.
        let (r, events) = a.set(set("min_depth", RosValue::Integer(1)));
        assert!(r.results[0].successful, "{:?}", r.results);
        let stored = RosValue::from(events[0].value.clone());
        assert_eq!(stored, RosValue::Double(1.0));
        let (r, events) = a.set_atomically(set("max_depth", RosValue::Integer(9)));
        assert!(r.result.successful);
        assert_eq!(
            RosValue::from(events[0].value.clone()),
            RosValue::Double(9.0)
        );
    }

    /// The fuse node's table: its names only, each read-only (its own value again accepted,
    /// unchanged), others not declared; `use_sim_time` beside them switches.
    #[test]
    fn a_fixed_table_serves_its_names_read_only() {
        let mut params = ParamSet::defaults();
        params
            .set("world_frame", &ParamValue::String("map".into()))
            .unwrap();
        let a = Answers::fixed(params, &["world_frame", "voxel_size"]);
        let listed = a.list(&ListParametersRequest {
            prefixes: vec![],
            depth: 0,
        });
        assert_eq!(listed.names, ["use_sim_time", "voxel_size", "world_frame"]);
        assert_eq!(a.value("world_frame"), RosValue::String("map".into()));
        assert_eq!(a.value("num_planes"), RosValue::NotSet, "not served");
        let d = describe(&a, "voxel_size");
        assert!(d.read_only && d.r#type == 3, "{d:?}");
        assert!(!describe(&a, USE_SIM_TIME).read_only);
        assert_eq!(describe(&a, "num_planes").r#type, 0);
        let types = a.types(&GetParameterTypesRequest {
            names: vec!["world_frame".into(), "num_planes".into()],
        });
        assert_eq!(types.values, [4, 0]);
        let set = |name: &str, value: RosValue| SetParametersRequest {
            parameter: vec![raw::Parameter::from(Parameter {
                name: name.into(),
                value,
            })],
        };
        let (r, events) = a.set(set("voxel_size", RosValue::Double(0.07)));
        assert!(!r.results[0].successful && events.is_empty());
        assert!(r.results[0].reason.contains("read-only"), "{r:?}");
        let (r, _) = a.set(set("num_planes", RosValue::Integer(32)));
        assert!(r.results[0].reason.contains("unknown parameter"), "{r:?}");
        let (r, events) = a.set(set("world_frame", RosValue::String("map".into())));
        assert!(r.results[0].successful && events.is_empty(), "{r:?}");
        let _clock = clock::TEST_SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        clock::set_use_sim_time(false);
        let both = SetParametersRequest {
            parameter: set(USE_SIM_TIME, RosValue::Boolean(true))
                .parameter
                .into_iter()
                .chain(set("voxel_size", RosValue::Double(0.07)).parameter)
                .collect(),
        };
        let (r, _) = a.set_atomically(both);
        assert!(!r.result.successful && !clock::uses_sim_time(), "none");
        let (r, events) = a.set(set(USE_SIM_TIME, RosValue::Boolean(true)));
        assert!(r.results[0].successful && events.len() == 1 && clock::uses_sim_time());
        clock::set_use_sim_time(false);
    }
}
