//! The node's parameter services (`~/list_parameters`, `~/get_parameters`,
//! `~/get_parameter_types`, `~/set_parameters`, `~/set_parameters_atomically`,
//! `~/describe_parameters`) and `/parameter_events`, served from the running configuration. Every
//! parameter has a descriptor: its type, what it sets, and `read_only` where a change needs the
//! world rebuilt (everything but `correct.*` and `node.debug_images_every`), so `ros2 param
//! describe` and rqt show which can be changed live.
//!
//! Owns the services only; what a parameter means and how it maps onto `Config` is `params`'s.

use super::log;
use super::params::{self, SIM_TIME};
use crate::config::Config;
use anyhow::{Result, anyhow};
use ros2_client::parameters::raw;
use ros2_client::qos::History;
use ros2_client::rcl_interfaces::{
    DescribeParametersRequest, DescribeParametersResponse, GetParameterTypesRequest,
    GetParameterTypesResponse, GetParametersRequest, GetParametersResponse, ListParametersRequest,
    ListParametersResponse, ListParametersResult, SetParametersAtomicallyResponse,
    SetParametersRequest, SetParametersResponse,
};
use ros2_client::{
    Message, Name, Node, Parameter, ParameterValue, Publisher, QosProfile, Server, ServiceMapping,
    ServiceTypeName,
};
use std::sync::{Arc, Mutex};

/// The live configuration the services read and change (the tick thread applies it).
type Live = Arc<Mutex<Config>>;

/// Every parameter with its value now.
fn current(live: &Live) -> Vec<(String, ParameterValue)> {
    let Ok(config) = live.lock() else {
        return Vec::new();
    };
    params::flatten(&config).unwrap_or_default()
}

fn value_of(all: &[(String, ParameterValue)], name: &str) -> ParameterValue {
    all.iter()
        .find(|(n, _)| n == name)
        .map_or(ParameterValue::NotSet, |(_, v)| v.clone())
}

/// The descriptor of `name`: read-only unless it applies from the next tick.
pub fn descriptor(name: &str, value: &ParameterValue) -> raw::ParameterDescriptor {
    let live = params::is_live(name);
    let section = name.split('.').next().unwrap_or(name);
    let description = match (name, section) {
        (n, _) if n == SIM_TIME.0 => "the node's clock is /clock instead of the wall clock".into(),
        (_, "correct") => format!("visual-force correction setting {name}"),
        (_, "node") => format!("ROS interface setting {name} (topics, frames, rates)"),
        (_, "robot") => format!("robot setting {name} (URDF, base, joint names)"),
        (_, "physics") => format!("physics setting {name}"),
        _ => format!("pegs setting {name}"),
    };
    let constraints = match live {
        true => "applied from the next tick".to_string(),
        false => format!("fixed once the node runs: restart with -p {name}:=VALUE"),
    };
    raw::ParameterDescriptor {
        name: name.to_string(),
        r#type: value.to_parameter_type() as u8,
        description,
        additional_constraints: constraints,
        read_only: !live,
        dynamic_typing: false,
        floating_point_range: Vec::new(),
        integer_range: Vec::new(),
    }
}

/// `config` with `name` set to `value`, if the value is valid and the parameter may change now.
fn set_one(config: &Config, name: &str, value: &ParameterValue) -> Result<Config, String> {
    let json =
        params::from_parameter(value).ok_or_else(|| format!("{name}: unsupported value type"))?;
    let next = params::with_parameter(config, name, json).map_err(|e| format!("{e:#}"))?;
    if next != *config && !params::is_live(name) {
        return Err(format!(
            "{name} is fixed once the node runs; restart with -p {name}:=VALUE"
        ));
    }
    Ok(next)
}

/// Names (and their prefixes) as `ros2 param list` asks for them: under `prefixes` (all when
/// empty), at most `depth` dot-separated levels deep (0: any depth).
fn list(all: &[(String, ParameterValue)], prefixes: &[String], depth: u64) -> ListParametersResult {
    let deep_enough = |s: &str| depth == 0 || (s.matches('.').count() as u64) < depth;
    let mut result = ListParametersResult {
        names: Vec::new(),
        prefixes: Vec::new(),
    };
    for (name, _) in all {
        let under = |prefix: &String| {
            name == prefix
                || name
                    .strip_prefix(prefix.as_str())
                    .and_then(|rest| rest.strip_prefix('.'))
                    .is_some_and(deep_enough)
        };
        if (prefixes.is_empty() && deep_enough(name)) || prefixes.iter().any(under) {
            result.names.push(name.clone());
            if let Some((prefix, _)) = name.rsplit_once('.')
                && !result.prefixes.iter().any(|p| p == prefix)
            {
                result.prefixes.push(prefix.to_string());
            }
        }
    }
    result
}

/// Serve one service: each request answered by `answer`, until the node stops.
fn serve<Req, Resp>(server: Server<Req, Resp>, answer: impl Fn(Req) -> Resp + Send + 'static)
where
    Req: Message + Clone + Send + Sync + 'static,
    Resp: Message + Send + Sync + 'static,
{
    tokio::spawn(async move {
        loop {
            match server.async_receive_request().await {
                Ok((id, request)) => {
                    if let Err(e) = server.async_send_response(id, answer(request)).await {
                        log(&format!("parameter service: cannot answer: {e:?}"));
                    }
                }
                Err(e) => log(&format!("parameter service: bad request: {e:?}")),
            }
        }
    });
}

/// Start the six parameter services of `node` on `live`, and `/parameter_events`.
pub fn start(context: &ros2_client::Context, node: &mut Node, live: Live) -> Result<()> {
    let fqn = node.fully_qualified_name();
    let qos = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
    macro_rules! server {
        ($name:expr, $ty:expr) => {
            node.create_server(
                ServiceMapping::Enhanced,
                &Name::new(&fqn, $name).map_err(|e| anyhow!("{e:?}"))?,
                &ServiceTypeName::new("rcl_interfaces", $ty),
                qos.clone(),
                qos.clone(),
            )
            .map_err(|e| anyhow!("parameter service {}: {e:?}", $name))?
        };
    }
    let events: Arc<Publisher<raw::ParameterEvent>> = Arc::new(
        node.create_publisher(&context.get_parameter_events_topic(), None)
            .map_err(|e| anyhow!("/parameter_events: {e:?}"))?,
    );
    let announce = {
        let fqn = fqn.clone();
        move |changed: Vec<(String, ParameterValue)>| {
            let event = raw::ParameterEvent {
                stamp: ros2_client::builtin_interfaces::Time::now(),
                node: fqn.clone(),
                new_parameters: Vec::new(),
                changed_parameters: changed
                    .into_iter()
                    .map(|(name, value)| raw::Parameter {
                        name,
                        value: value.into(),
                    })
                    .collect(),
                deleted_parameters: Vec::new(),
            };
            if let Err(e) = events.publish(event) {
                log(&format!("/parameter_events: {e:?}"));
            }
        }
    };

    let l = live.clone();
    serve(
        server!("list_parameters", "ListParameters"),
        move |r: ListParametersRequest| ListParametersResponse {
            result: list(&current(&l), &r.prefixes, r.depth),
        },
    );
    let l = live.clone();
    serve(
        server!("get_parameters", "GetParameters"),
        move |r: GetParametersRequest| {
            let all = current(&l);
            let values = r.names.iter().map(|n| value_of(&all, n).into()).collect();
            GetParametersResponse { values }
        },
    );
    let l = live.clone();
    serve(
        server!("get_parameter_types", "GetParameterTypes"),
        move |r: GetParameterTypesRequest| {
            let all = current(&l);
            let values = r.names.iter();
            let values = values.map(|n| value_of(&all, n).to_parameter_type() as u8);
            GetParameterTypesResponse {
                values: values.collect(),
            }
        },
    );
    let l = live.clone();
    serve(
        server!("describe_parameters", "DescribeParameters"),
        move |r: DescribeParametersRequest| {
            let all = current(&l);
            let values = r.names.iter();
            let values = values.map(|n| descriptor(n, &value_of(&all, n)));
            DescribeParametersResponse {
                values: values.collect(),
            }
        },
    );
    let (l, tell) = (live.clone(), announce.clone());
    serve(
        server!("set_parameters", "SetParameters"),
        move |r: SetParametersRequest| {
            let results = r.parameter.into_iter().map(Parameter::from).map(|p| {
                let outcome = apply(&l, std::slice::from_ref(&p));
                if outcome.is_ok() {
                    tell(vec![(p.name, p.value)]);
                }
                result(outcome)
            });
            SetParametersResponse {
                results: results.collect(),
            }
        },
    );
    let (l, tell) = (live, announce);
    serve(
        server!("set_parameters_atomically", "SetParametersAtomically"),
        move |r: SetParametersRequest| {
            let all: Vec<Parameter> = r.parameter.into_iter().map(Parameter::from).collect();
            let outcome = apply(&l, &all);
            if outcome.is_ok() {
                tell(all.into_iter().map(|p| (p.name, p.value)).collect());
            }
            SetParametersAtomicallyResponse {
                result: result(outcome),
            }
        },
    );
    Ok(())
}

/// Set every parameter of `all` or none; the tick thread applies the change from its next tick.
fn apply(live: &Live, all: &[Parameter]) -> Result<(), String> {
    let mut config = live
        .lock()
        .map_err(|_| "configuration lock poisoned".to_string())?;
    let mut next = config.clone();
    for p in all {
        next = set_one(&next, &p.name, &p.value)?;
    }
    if next != *config {
        for p in all {
            log(&format!(
                "parameter {} set to {:?}; applied from the next tick",
                p.name, p.value
            ));
        }
        *config = next;
    }
    Ok(())
}

fn result(outcome: Result<(), String>) -> raw::SetParametersResult {
    match outcome {
        Ok(()) => raw::SetParametersResult {
            successful: true,
            reason: String::new(),
        },
        Err(reason) => raw::SetParametersResult {
            successful: false,
            reason,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What can change live is writable; what builds the world is read-only and says how to
    /// change it; a set is all-or-nothing.
    #[test]
    fn descriptors_say_which_parameters_change_live_and_sets_are_all_or_nothing() {
        let gain = descriptor("correct.gain", &ParameterValue::Double(1.0));
        assert!(!gain.read_only && gain.r#type == 3 && !gain.description.is_empty());
        let dt = descriptor("physics.dt", &ParameterValue::Double(0.03));
        assert!(dt.read_only && dt.additional_constraints.contains("restart"));
        assert!(descriptor("use_sim_time", &ParameterValue::Boolean(false)).read_only);
        let live: Live = Arc::new(Mutex::new(Config::default()));
        let set = |name: &str, v: f64| Parameter {
            name: name.into(),
            value: ParameterValue::Double(v),
        };
        assert!(apply(&live, &[set("correct.gain", 900.0)]).is_ok());
        let before = live.lock().unwrap().clone();
        assert_eq!(before.correct.gain, 900.0);
        let refused = apply(
            &live,
            &[set("correct.gain", 700.0), set("physics.dt", 0.01)],
        );
        assert!(refused.unwrap_err().contains("physics.dt is fixed"));
        assert_eq!(
            *live.lock().unwrap(),
            before,
            "nothing of a refused set applies"
        );
        let all = current(&live);
        let listed = list(&all, &["correct".into()], 1);
        assert!(listed.names.contains(&"correct.gain".to_string()));
        assert!(!listed.names.iter().any(|n| n.starts_with("physics")));
        assert!(
            list(&all, &[], 1)
                .names
                .contains(&"use_sim_time".to_string())
        );
    }
}
