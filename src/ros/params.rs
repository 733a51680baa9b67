//! The configuration as ROS 2 parameters: every scalar and flat list of `Config` becomes a
//! parameter named by its path (`correct.gain`, `physics.ground.height`, ...), launch-time
//! overrides (`--ros-args -p name:=value`, `--params-file FILE`) are applied to the
//! configuration before it is validated, and runtime sets are checked against the same rules.
//!
//! Owns the translation between `Config` and parameters only; applying a change to a running
//! tracker is the node's job.

use crate::config::Config;
use anyhow::{Context, Result, bail};
use ros2_client::ParameterValue;
use serde_json::Value;
use std::path::PathBuf;

/// Parameters that take effect while the node runs (applied at the next tick); every other
/// parameter is fixed at start (the world and its robot are built from it).
pub fn is_live(name: &str) -> bool {
    (name.starts_with("correct.") && name != "correct.backend") || name == "node.debug_images_every"
}

/// `config` as (name, value) parameters. Empty lists, nulls and lists of mappings (object and
/// effect lists) have no parameter type and are left out; they are set in the parameter file.
pub fn flatten(config: &Config) -> Result<Vec<(String, ParameterValue)>> {
    let mut out = Vec::new();
    walk(&serde_json::to_value(config)?, String::new(), &mut out);
    Ok(out)
}

fn walk(value: &Value, path: String, out: &mut Vec<(String, ParameterValue)>) {
    let join = |key: &str| {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    };
    match value {
        Value::Object(map) => map.iter().for_each(|(k, v)| walk(v, join(k), out)),
        other => {
            if let Some(p) = to_parameter(other) {
                out.push((path, p));
            }
        }
    }
}

fn to_parameter(value: &Value) -> Option<ParameterValue> {
    Some(match value {
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) if n.is_i64() || n.is_u64() => ParameterValue::Integer(n.as_i64()?),
        Value::Number(n) => ParameterValue::Double(n.as_f64()?),
        Value::String(s) => ParameterValue::String(s.clone()),
        // An empty list is declared as an empty string array (its type is unknown; what is set
        // later is checked against the configuration like any value).
        Value::Array(items) if items.is_empty() => ParameterValue::StringArray(Vec::new()),
        Value::Array(items) => {
            if items.iter().all(Value::is_number) {
                ParameterValue::DoubleArray(items.iter().filter_map(Value::as_f64).collect())
            } else if items.iter().all(Value::is_string) {
                ParameterValue::StringArray(
                    items
                        .iter()
                        .filter_map(|s| s.as_str().map(String::from))
                        .collect(),
                )
            } else if items.iter().all(Value::is_boolean) {
                ParameterValue::BooleanArray(items.iter().filter_map(Value::as_bool).collect())
            } else {
                return None;
            }
        }
        _ => return None,
    })
}

/// A parameter value as the configuration's JSON value.
pub fn from_parameter(p: &ParameterValue) -> Option<Value> {
    Some(match p {
        ParameterValue::Boolean(b) => Value::from(*b),
        ParameterValue::Integer(i) => Value::from(*i),
        ParameterValue::Double(d) => Value::from(*d),
        ParameterValue::String(s) => Value::from(s.clone()),
        ParameterValue::DoubleArray(v) => Value::from(v.clone()),
        ParameterValue::IntegerArray(v) => Value::from(v.clone()),
        ParameterValue::StringArray(v) => Value::from(v.clone()),
        ParameterValue::BooleanArray(v) => Value::from(v.clone()),
        ParameterValue::NotSet | ParameterValue::ByteArray(_) => return None,
    })
}

/// `config` with the parameter `name` set to `value`, validated like a configuration file.
pub fn with_parameter(config: &Config, name: &str, value: Value) -> Result<Config> {
    let mut tree = serde_json::to_value(config)?;
    let mut at = &mut tree;
    for key in name.split('.') {
        at = at
            .as_object_mut()
            .and_then(|m| m.get_mut(key))
            .with_context(|| format!("no parameter '{name}'"))?;
    }
    // Integers are accepted where the configuration holds a real number.
    *at = match (&*at, value) {
        (Value::Number(old), Value::Number(new)) if old.is_f64() => {
            Value::from(new.as_f64().unwrap_or(f64::NAN))
        }
        (_, v) => v,
    };
    let config: Config = serde_json::from_value(tree)
        .with_context(|| format!("parameter '{name}' has the wrong type"))?;
    config
        .validated()
        .with_context(|| format!("parameter '{name}'"))
}

/// What `--ros-args` asked for.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LaunchArgs {
    pub params_files: Vec<PathBuf>,
    /// `-p name:=value`, value as YAML text.
    pub overrides: Vec<(String, String)>,
    /// `-r __node:=name`
    pub node_name: Option<String>,
    /// `-r __ns:=/namespace`
    pub namespace: Option<String>,
}

/// Parse the arguments after `--ros-args` (up to an optional `--`).
pub fn parse_ros_args(args: &[String]) -> Result<LaunchArgs> {
    let mut out = LaunchArgs::default();
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--" => break,
            "-p" | "--param" => {
                let item = it.next().context("-p needs name:=value")?;
                let (name, value) = item
                    .split_once(":=")
                    .with_context(|| format!("-p {item}: expected name:=value"))?;
                out.overrides.push((name.to_string(), value.to_string()));
            }
            "--params-file" => out
                .params_files
                .push(it.next().context("--params-file needs a file")?.into()),
            "-r" | "--remap" => {
                let item = it.next().context("-r needs from:=to")?;
                match item.split_once(":=") {
                    Some(("__node" | "__name", name)) => out.node_name = Some(name.to_string()),
                    Some(("__ns", ns)) => out.namespace = Some(ns.to_string()),
                    _ => bail!("-r {item}: only __node:= and __ns:= remaps are supported"),
                }
            }
            // Accepted and ignored: logging options.
            "--log-level" | "--enclave" => {
                it.next();
            }
            "--ros-args" => {}
            other => bail!(
                "unsupported ROS argument '{other}' (supported: -p, --params-file, -r __node:=, -r __ns:=, --log-level)"
            ),
        }
    }
    Ok(out)
}

/// The configuration the node starts with: `base` (a file or the defaults), then each
/// `--params-file` in order, then each `-p`.
pub fn launch_config(base: Config, args: &LaunchArgs) -> Result<Config> {
    let mut config = base;
    for file in &args.params_files {
        let text = std::fs::read_to_string(file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(&text)
            .with_context(|| format!("{} is not valid YAML", file.display()))?;
        let params = crate::config::ros_parameters(&yaml).unwrap_or(&yaml);
        let mut leaves = Vec::new();
        leaves_of(&serde_json::to_value(params)?, String::new(), &mut leaves);
        for (name, value) in leaves {
            config = with_parameter(&config, &name, value)
                .with_context(|| format!("in {}", file.display()))?;
        }
    }
    for (name, text) in &args.overrides {
        let value: serde_yaml_ng::Value = serde_yaml_ng::from_str(text)
            .with_context(|| format!("-p {name}:={text}: not a value"))?;
        config = with_parameter(&config, name, serde_json::to_value(value)?)
            .with_context(|| format!("-p {name}:={text}"))?;
    }
    Ok(config)
}

/// Every leaf (non-mapping value) of a tree with its dotted path.
fn leaves_of(value: &Value, path: String, out: &mut Vec<(String, Value)>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                leaves_of(
                    v,
                    if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    },
                    out,
                );
            }
        }
        other => out.push((path, other.clone())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_flat_parameter_sets_back_to_the_same_configuration() {
        let config = Config::default();
        let params = flatten(&config).unwrap();
        let names: Vec<&str> = params.iter().map(|(n, _)| n.as_str()).collect();
        for expected in [
            "physics.dt",
            "physics.ground.height",
            "correct.gain",
            "physics.gravity",
            "node.cameras",
        ] {
            assert!(
                names.contains(&expected),
                "{expected} missing from {names:?}"
            );
        }
        for (name, value) in &params {
            let back = with_parameter(&config, name, from_parameter(value).unwrap()).unwrap();
            assert_eq!(back, config, "{name}");
        }
    }

    #[test]
    fn a_set_changes_only_its_field_and_bad_values_are_refused() {
        let config = Config::default();
        let c = with_parameter(&config, "correct.gain", Value::from(0.5)).unwrap();
        assert_eq!(c.correct.gain, 0.5);
        assert_eq!(c.physics, config.physics);
        let c = with_parameter(&config, "physics.substeps", Value::from(7)).unwrap();
        assert_eq!(c.physics.substeps, 7);
        // An integer where a real number is expected is fine.
        assert_eq!(
            with_parameter(&config, "correct.gain", Value::from(2))
                .unwrap()
                .correct
                .gain,
            2.0
        );
        assert!(
            format!(
                "{:#}",
                with_parameter(&config, "physics.dt", Value::from(-1.0)).unwrap_err()
            )
            .contains("physics.dt")
        );
        assert!(
            format!(
                "{:#}",
                with_parameter(&config, "physics.nonsense", Value::from(1.0)).unwrap_err()
            )
            .contains("no parameter")
        );
        assert!(with_parameter(&config, "physics.substeps", Value::from("many")).is_err());
    }

    #[test]
    fn ros_args_overrides_apply_after_params_files() {
        let dir = std::env::temp_dir().join(format!("pegs-params-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("p.yaml");
        std::fs::write(
            &file,
            "pegs:\n  ros__parameters:\n    correct:\n      gain: 0.7\n      damping: 0.02\n",
        )
        .unwrap();
        let args: Vec<String> = [
            "--params-file",
            file.to_str().unwrap(),
            "-p",
            "correct.gain:=0.9",
            "-p",
            "node.cameras:=[a, b]",
            "-r",
            "__node:=tracker",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let parsed = parse_ros_args(&args).unwrap();
        assert_eq!(parsed.node_name.as_deref(), Some("tracker"));
        let c = launch_config(Config::default(), &parsed).unwrap();
        assert_eq!(c.correct.gain, 0.9);
        assert_eq!(c.correct.damping, 0.02);
        assert_eq!(c.node.cameras, vec!["a".to_string(), "b".to_string()]);
        assert!(parse_ros_args(&["-p".into(), "gain".into()]).is_err());
        assert!(
            launch_config(
                Config::default(),
                &parse_ros_args(&["-p".into(), "physics.dt:=0".into()]).unwrap()
            )
            .is_err()
        );
    }

    #[test]
    fn only_correction_and_output_rates_are_live() {
        assert!(is_live("correct.gain"));
        assert!(!is_live("correct.backend"));
        assert!(!is_live("physics.dt"));
    }
}
