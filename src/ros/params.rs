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
/// parameter is fixed at start (the world and its robot are built from it, and the depth
/// subscription is kept or dropped by `correct.pose_search_depth`).
pub fn is_live(name: &str) -> bool {
    let fixed = ["correct.backend", "correct.pose_search_depth"];
    (name.starts_with("correct.") && !fixed.contains(&name)) || name == "node.debug_images_every"
}

/// The configuration's `node.use_sim_time` is the parameter every ROS node has: `use_sim_time`.
pub const SIM_TIME: (&str, &str) = ("use_sim_time", "node.use_sim_time");

/// The configuration path of parameter `name`.
fn path_of(name: &str) -> &str {
    if name == SIM_TIME.0 { SIM_TIME.1 } else { name }
}

/// `config` as (name, value) parameters. Empty lists, nulls and lists of mappings (object and
/// effect lists) have no parameter type and are left out; they are set in the parameter file.
pub fn flatten(config: &Config) -> Result<Vec<(String, ParameterValue)>> {
    let mut out = Vec::new();
    walk(&serde_json::to_value(config)?, String::new(), &mut out);
    for (name, _) in &mut out {
        if name == SIM_TIME.1 {
            *name = SIM_TIME.0.to_string();
        }
    }
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
    for key in path_of(name).split('.') {
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
    /// `-r /from:=/to`: topic remaps.
    pub remaps: Remaps,
}

/// Topic names as rcl resolves them for this node: `/name` is absolute, `~/name` lies under the
/// node (`/ns/node/name`), any other name under its namespace (`/ns/name`); then the first
/// `-r from:=to` rule whose `from` resolves to the same name renames it (`to` resolved alike).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Remaps {
    pub rules: Vec<(String, String)>,
    /// The node's namespace (empty or `/`: the root) and name (empty: `pegs`).
    pub namespace: String,
    pub node: String,
}

impl Remaps {
    /// `name` resolved against the node's namespace and name, before remapping.
    pub fn expand(&self, name: &str) -> String {
        let ns = self.namespace.trim_matches('/');
        let ns = if ns.is_empty() {
            String::new()
        } else {
            format!("/{ns}")
        };
        let node = if self.node.is_empty() {
            "pegs"
        } else {
            &self.node
        };
        let full = if let Some(absolute) = name.strip_prefix('/') {
            format!("/{absolute}")
        } else if let Some(private) = name.strip_prefix('~') {
            format!("{ns}/{node}/{}", private.trim_start_matches('/'))
        } else {
            format!("{ns}/{name}")
        };
        full.trim_end_matches('/').to_string()
    }

    /// The topic `name` resolves to, remapped.
    pub fn apply(&self, name: &str) -> String {
        let full = self.expand(name);
        self.rules
            .iter()
            .find(|(from, _)| self.expand(from) == full)
            .map_or(full, |(_, to)| self.expand(to))
    }
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
                    Some((from, to)) if !from.starts_with("__") && !to.is_empty() => {
                        out.remaps.rules.push((from.to_string(), to.to_string()))
                    }
                    _ => bail!(
                        "-r {item}: expected /topic:=/other, __node:=name or __ns:=/namespace"
                    ),
                }
            }
            // Accepted and ignored: logging options.
            "--log-level" | "--enclave" => {
                it.next();
            }
            "--ros-args" => {}
            other => bail!(
                "unsupported ROS argument '{other}' (supported: -p, --params-file, -r from:=to, -r __node:=, -r __ns:=, --log-level)"
            ),
        }
    }
    out.remaps.namespace = out.namespace.clone().unwrap_or_default();
    out.remaps.node = out.node_name.clone().unwrap_or_default();
    Ok(out)
}

/// The configuration the node starts with: `base` (a file or the defaults), then each
/// `--params-file` in order, then each `-p`. A parameter file applies, in its order, the sections
/// whose key matches the node's fully qualified name as rcl matches them (`/ns/name`, `name`, `/**`,
/// `/**/name`, `*` for one token); keys a wildcard section sets that pegs does not have (another
/// node's parameters) are ignored with a log line, while an unknown key in the node's own section is
/// an error. `use_sim_time` sets `node.use_sim_time`.
pub fn launch_config(base: Config, args: &LaunchArgs) -> Result<Config> {
    let node = fully_qualified_name(args);
    let mut config = base;
    for file in &args.params_files {
        let text = std::fs::read_to_string(file)
            .with_context(|| format!("cannot read {}", file.display()))?;
        let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(&text)
            .with_context(|| format!("{} is not valid YAML", file.display()))?;
        for (key, params) in sections_for(&yaml, &node) {
            let wildcard = key.contains('*');
            let mut leaves = Vec::new();
            leaves_of(&serde_json::to_value(params)?, String::new(), &mut leaves);
            for (name, value) in leaves {
                if wildcard && !is_parameter(&config, &name) {
                    super::log(&format!(
                        "{}: '{name}' under '{key}' is not a pegs parameter; ignored",
                        file.display()
                    ));
                    continue;
                }
                config = with_parameter(&config, &name, value)
                    .with_context(|| format!("in {} under '{key}'", file.display()))?;
            }
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

/// The node's fully qualified name from `-r __ns:=` and `-r __node:=` (default `/pegs`).
pub fn fully_qualified_name(args: &LaunchArgs) -> String {
    let ns = args
        .namespace
        .as_deref()
        .unwrap_or("/")
        .trim_end_matches('/');
    let name = args.node_name.as_deref().unwrap_or("pegs");
    format!("{ns}/{name}")
}

/// The `ros__parameters` sections of a parameter file that apply to `node`, with their keys, in
/// file order. A file without node sections (pegs's own layout) applies whole.
fn sections_for<'a>(
    yaml: &'a serde_yaml_ng::Value,
    node: &str,
) -> Vec<(String, &'a serde_yaml_ng::Value)> {
    let Some(map) = yaml.as_mapping() else {
        return Vec::new();
    };
    let sections: Vec<(String, &serde_yaml_ng::Value)> = map
        .iter()
        .filter_map(|(k, v)| {
            Some((
                k.as_str()?.to_string(),
                v.as_mapping()?.get("ros__parameters")?,
            ))
        })
        .collect();
    if sections.is_empty() {
        return vec![(node.to_string(), yaml)];
    }
    sections
        .into_iter()
        .filter(|(key, _)| node_key_matches(key, node))
        .collect()
}

/// Whether a parameter-file key (`/ns/name`, `name`, with `**` for any number of tokens and `*`
/// for one) names the node `/ns/name`.
pub fn node_key_matches(key: &str, node: &str) -> bool {
    fn tokens(s: &str) -> Vec<&str> {
        s.split('/').filter(|t| !t.is_empty()).collect()
    }
    fn matches(pattern: &[&str], name: &[&str]) -> bool {
        match (pattern.first(), name.first()) {
            (None, None) => true,
            (Some(&"**"), _) => {
                matches(&pattern[1..], name) || (!name.is_empty() && matches(pattern, &name[1..]))
            }
            (Some(p), Some(n)) if *p == "*" || p == n => matches(&pattern[1..], &name[1..]),
            _ => false,
        }
    }
    // With or without its leading '/', a key is a path from the root: `pegs` is `/pegs`.
    matches(&tokens(key), &tokens(node))
}

/// Whether `name` is a parameter of the configuration (a path to a leaf).
fn is_parameter(config: &Config, name: &str) -> bool {
    let Ok(tree) = serde_json::to_value(config) else {
        return false;
    };
    let mut at = &tree;
    for key in path_of(name).split('.') {
        match at.as_object().and_then(|m| m.get(key)) {
            Some(next) => at = next,
            None => return false,
        }
    }
    true
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
            "tracker:\n  ros__parameters:\n    correct:\n      gain: 0.7\n      damping: 0.02\n",
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
        assert!(!is_live("correct.pose_search_depth"));
        assert!(!is_live("physics.dt"));
    }

    /// A multi-node parameter file as ROS users write them: `/**` for every node (with keys other
    /// nodes use), the node by name, another node's section. The node takes `/**` and its own
    /// section in file order, ignores the others and the foreign `/**` keys, and refuses an unknown
    /// key in its own section; `use_sim_time` is the node's clock setting.
    #[test]
    fn parameter_files_apply_the_sections_that_name_the_node() {
        let remaps = parse_ros_args(&["-r".into(), "/joint_states:=/fr3/joint_states".into()])
            .unwrap()
            .remaps;
        assert_eq!(remaps.apply("/joint_states"), "/fr3/joint_states");
        assert_eq!(remaps.apply("joint_states"), "/fr3/joint_states");
        assert_eq!(remaps.apply("/tf"), "/tf");
        // Relative and private names resolve against the namespace and node, remaps alike.
        let args: Vec<String> = [
            "-r",
            "__ns:=/rig",
            "-r",
            "__node:=tracker",
            "-r",
            "joint_states:=arm/joint_states",
        ]
        .map(String::from)
        .to_vec();
        let names = parse_ros_args(&args).unwrap().remaps;
        assert_eq!(names.apply("joint_states"), "/rig/arm/joint_states");
        assert_eq!(names.apply("/rig/joint_states"), "/rig/arm/joint_states");
        assert_eq!(names.apply("~/objects"), "/rig/tracker/objects");
        assert_eq!(names.apply("~"), "/rig/tracker");
        assert_eq!(
            names.apply("/camera/cam0/color/image_raw"),
            "/camera/cam0/color/image_raw"
        );
        assert_eq!(Remaps::default().apply("~/objects"), "/pegs/objects");
        assert!(parse_ros_args(&["-r".into(), "__bad:=x".into()]).is_err());
        assert!(node_key_matches("/**", "/pegs"));
        assert!(node_key_matches("pegs", "/pegs"));
        assert!(node_key_matches("/**/pegs", "/rig/pegs"));
        assert!(node_key_matches("/rig/*", "/rig/pegs"));
        assert!(!node_key_matches("pegs", "/rig/pegs"));
        assert!(!node_key_matches("/camera/cam0", "/pegs"));
        let dir = std::env::temp_dir().join(format!("pegs-params-multi-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("rig.yaml");
        std::fs::write(
            &file,
            "/**:\n  ros__parameters:\n    use_sim_time: false\n    align_depth.enable: true\n    \
             correct:\n      gain: 0.5\n/camera/cam0:\n  ros__parameters:\n    correct:\n      \
             gain: 9.0\n    serial_no: '123'\npegs:\n  ros__parameters:\n    correct:\n      \
             damping: 0.03\n",
        )
        .unwrap();
        let args = |extra: &[&str]| {
            let mut a = vec!["--params-file".to_string(), file.display().to_string()];
            a.extend(extra.iter().map(|s| s.to_string()));
            parse_ros_args(&a).unwrap()
        };
        let c = launch_config(Config::default(), &args(&[])).unwrap();
        assert_eq!((c.correct.gain, c.correct.damping), (0.5, 0.03));
        // Renamed, the `pegs` section no longer applies; `/**` still does.
        let c = launch_config(Config::default(), &args(&["-r", "__node:=tracker"])).unwrap();
        assert_eq!(c.correct.gain, 0.5);
        assert_eq!(c.correct.damping, Config::default().correct.damping);
        std::fs::write(&file, "pegs:\n  ros__parameters:\n    gain: 1.0\n").unwrap();
        let e = format!(
            "{:#}",
            launch_config(Config::default(), &args(&[])).unwrap_err()
        );
        assert!(e.contains("no parameter 'gain'"), "{e}");
        std::fs::write(&file, "/**:\n  ros__parameters:\n    use_sim_time: true\n").unwrap();
        let c = launch_config(Config::default(), &args(&[])).unwrap();
        assert!(c.node.use_sim_time, "use_sim_time is node.use_sim_time");
        let c = launch_config(Config::default(), &args(&["-p", "use_sim_time:=true"])).unwrap();
        assert!(c.node.use_sim_time);
        let names: Vec<String> = flatten(&c).unwrap().into_iter().map(|(n, _)| n).collect();
        assert!(names.contains(&"use_sim_time".to_string()));
        assert!(
            !names.iter().any(|n| n == "node.use_sim_time"),
            "declared once, by its ROS name"
        );
    }
}
