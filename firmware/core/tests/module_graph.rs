//! The core's modules import each other in one direction only: from the model (`model`,
//! `model_ram`) down through the stages to the kernels (`dsp`) and tables (`activation`,
//! `const_math`, `fixed`). A module that needs a type of a module that needs it back means the
//! type is in the wrong home (a kernel's parameter struct belongs with the kernel).
//!
//! Reads `src/` and collects every `crate::<module>` path outside comments and `#[cfg(test)]`
//! blocks at the end of a file.
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

fn module_of(rel: &Path) -> String {
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

fn edges() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = vec![src.clone()];
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    while let Some(p) = files.pop() {
        if p.is_dir() {
            files.extend(std::fs::read_dir(&p).unwrap().map(|e| e.unwrap().path()));
            continue;
        }
        let rel = p.strip_prefix(&src).unwrap();
        let m = module_of(rel);
        if m == "lib" {
            continue;
        }
        let text = std::fs::read_to_string(&p).unwrap();
        // Unit tests may use any module.
        let body = text.split("#[cfg(test)]\nmod tests").next().unwrap();
        for line in body.lines() {
            let code = line.split("//").next().unwrap();
            for (i, _) in code.match_indices("crate::") {
                let name: String = code[i + 7..]
                    .chars()
                    .take_while(|c| c.is_ascii_lowercase() || *c == '_')
                    .collect();
                if !name.is_empty() && name != m {
                    g.entry(m.clone()).or_default().insert(name);
                }
            }
        }
    }
    g
}

fn reaches(g: &BTreeMap<String, BTreeSet<String>>, from: &str, to: &str) -> bool {
    let mut seen = BTreeSet::new();
    let mut stack = vec![from.to_string()];
    while let Some(m) = stack.pop() {
        for n in g.get(&m).into_iter().flatten() {
            if n == to {
                return true;
            }
            if seen.insert(n.clone()) {
                stack.push(n.clone());
            }
        }
    }
    false
}

#[test]
fn core_modules_have_no_import_cycle() {
    let g = edges();
    assert!(
        g.get("model").is_some_and(|d| d.contains("lstm")),
        "the scan found no imports: {g:?}"
    );
    let cycles: Vec<String> = g
        .iter()
        .flat_map(|(a, ds)| ds.iter().map(move |b| (a, b)))
        .filter(|(a, b)| reaches(&g, b, a))
        .map(|(a, b)| format!("{a} -> {b}"))
        .collect();
    assert!(cycles.is_empty(), "imports on a cycle: {cycles:?}");
}
