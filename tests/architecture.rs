//! The layering of the library, as the README's Layout table states it: every `crate::` path in a
//! module of `src/` names a module of a lower layer (tests inside modules included). Fails on an
//! import that goes sideways or up, on a module the table does not place, and on a table that
//! names a module `src/` does not have.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Module -> layer, from the rows between the README's layers markers.
fn layers() -> BTreeMap<String, usize> {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let start = readme
        .find("<!-- layers:start -->")
        .expect("README has no layers table");
    let end = readme
        .find("<!-- layers:end -->")
        .expect("README has no layers table end");
    let mut out = BTreeMap::new();
    for row in readme[start..end].lines().filter(|l| l.starts_with("| ")) {
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        let Ok(layer) = cells[1].parse::<usize>() else {
            continue;
        };
        for module in cells[2].split(',') {
            let name = module.trim().trim_matches('`').to_string();
            assert!(
                out.insert(name.clone(), layer).is_none(),
                "{name} placed twice"
            );
        }
    }
    out
}

/// Every `.rs` file under `dir`.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level modules named by `crate::name` and `crate::{a, b::c}` paths in `text` (comments
/// left out).
fn imports(text: &str) -> Vec<String> {
    let code: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = Vec::new();
    for (at, _) in code.match_indices("crate::") {
        let rest = &code[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let inner = &group[..group.find('}').unwrap_or(group.len())];
            out.extend(
                inner
                    .split(',')
                    .map(|p| ident(p.trim()))
                    .filter(|m| !m.is_empty()),
            );
        } else {
            out.push(ident(rest));
        }
    }
    out
}

#[test]
fn every_module_imports_only_lower_layers() {
    let layers = layers();
    let src = root().join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut modules_seen = std::collections::BTreeSet::new();
    let mut wrong = Vec::new();
    for file in files {
        let relative = file.strip_prefix(&src).unwrap();
        let first = relative
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let Some(&layer) = layers.get(&module) else {
            wrong.push(format!(
                "{module} ({}) is not in the README's layers table",
                relative.display()
            ));
            continue;
        };
        modules_seen.insert(module.clone());
        let text = std::fs::read_to_string(&file).unwrap();
        for used in imports(&text) {
            if used == module {
                continue;
            }
            match layers.get(&used) {
                Some(&l) if l < layer => {}
                Some(&l) => wrong.push(format!(
                    "{} (layer {layer}) imports {used} (layer {l})",
                    relative.display()
                )),
                None => wrong.push(format!(
                    "{} imports {used}, which has no layer",
                    relative.display()
                )),
            }
        }
    }
    for module in layers.keys().filter(|m| !modules_seen.contains(*m)) {
        wrong.push(format!(
            "the layers table names {module}, which src/ does not have"
        ));
    }
    assert!(wrong.is_empty(), "layering broken:\n{}", wrong.join("\n"));
}

#[test]
fn the_import_reader_sees_grouped_and_nested_paths() {
    let text = "use crate::world::{World, ShapeId};\nuse crate::{physics, render::Camera};\n// crate::demo\nlet x = crate::math::Pose::IDENTITY;";
    assert_eq!(imports(text), ["world", "physics", "render", "math"]);
}
