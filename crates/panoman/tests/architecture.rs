//! `docs/design/architecture.md` §2 lists the crates so that each depends only on crates above
//! it: that order, and the list itself, are checked against every crate's `Cargo.toml`.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The crates of the architecture table, in order (first column, backquoted names).
fn table_order(doc: &str) -> Vec<String> {
    let start = doc.find("| crate | owns |").expect("the crate table");
    doc[start..]
        .lines()
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            let cell = l.split('|').nth(1).expect("a first cell").trim();
            cell.trim_matches('`').to_string()
        })
        .collect()
}

/// The workspace crates a manifest names (dependencies of every kind).
fn workspace_deps(manifest: &str, crates: &[String]) -> Vec<String> {
    manifest
        .lines()
        .filter_map(|l| {
            let name = l.split(['.', '=', ' ']).next()?.trim();
            crates.iter().find(|c| c.as_str() == name).cloned()
        })
        .collect()
}

#[test]
fn the_crate_table_lists_every_crate_below_its_dependencies() {
    let doc = std::fs::read_to_string(root().join("docs/design/architecture.md")).unwrap();
    let order = table_order(&doc);
    let mut on_disk: Vec<String> = std::fs::read_dir(root().join("crates"))
        .unwrap()
        .filter_map(|e| {
            let e = e.ok()?;
            e.path()
                .join("Cargo.toml")
                .exists()
                .then(|| e.file_name().to_string_lossy().into_owned())
        })
        .collect();
    on_disk.sort();
    let mut listed = order.clone();
    listed.sort();
    assert_eq!(
        listed, on_disk,
        "the table's crates against crates/*/Cargo.toml"
    );
    let mut edges = 0;
    for (i, c) in order.iter().enumerate() {
        let manifest = std::fs::read_to_string(root().join("crates").join(c).join("Cargo.toml"))
            .unwrap_or_else(|e| panic!("{c}: {e}"));
        // The first line naming the crate is its own `name = …`; skip the [package] table.
        let deps_part = &manifest[manifest.find("dependencies").unwrap_or(0)..];
        for d in workspace_deps(deps_part, &order) {
            edges += 1;
            let j = order.iter().position(|x| *x == d).expect("listed");
            assert!(
                j < i,
                "{c} depends on {d}, which the table lists below it (docs/design/architecture.md §2)"
            );
        }
    }
    // The manifests were read: the CLI alone depends on most crates of the workspace.
    assert!(
        edges >= order.len(),
        "only {edges} dependencies found in the manifests"
    );
}
