//! The runner and the QC API read what the project stores through its types
//! (decision 0080): never a stored document by a JSON key, so that renaming
//! a member of `MeasurementConfig`, `JobProblem` or `StoredRequest` is a
//! compile error in every reader, not a silent `null`.

/// The QC API's files that read stored documents back (with [`RUNNER`]).
const API_QC: [(&str, &str); 5] = [
    ("src/api/qc/limits.rs", include_str!("../api/qc/limits.rs")),
    (
        "src/api/qc/recipes.rs",
        include_str!("../api/qc/recipes.rs"),
    ),
    (
        "src/api/qc/verdicts.rs",
        include_str!("../api/qc/verdicts.rs"),
    ),
    ("src/api/qc/outbox.rs", include_str!("../api/qc/outbox.rs")),
    ("src/api/qc/mod.rs", include_str!("../api/qc/mod.rs")),
];

/// Ways of reading a stored document by key.
const BY_KEY: [&str; 9] = [
    "pointer(",
    "[\"detail\"]",
    "[\"type\"]",
    ".config.get(",
    ".config[",
    "config[\"",
    "from_value(job.request",
    "request.get(\"type\")",
    // a limit proposal's recipe (the approval read `p.proposal["recipe"]`)
    ".proposal[",
];

#[test]
fn stored_documents_are_read_through_their_types() {
    let mut found = vec![];
    for (path, text) in RUNNER.iter().chain(&API_QC) {
        for (i, line) in text.lines().enumerate() {
            if line.trim_start().starts_with("//") {
                continue;
            }
            for p in BY_KEY {
                if line.contains(p) {
                    found.push(format!("{path}:{}: `{p}`: {}", i + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "a stored document read by key (use its type's members):\n{}",
        found.join("\n")
    );
}

/// The runner's files. They read stored documents through their types (the
/// test above, with [`API_QC`]), and what they store they make from the
/// project's types (decision 0080); a document built with `json!` is a bag
/// no type checks
/// (the calibration record's sensors were one until session 22: a renamed
/// member would have gone unnoticed and forced a self-check after every
/// upgrade).
const RUNNER: [(&str, &str); 9] = [
    ("src/runner/mod.rs", include_str!("mod.rs")),
    ("src/runner/execute.rs", include_str!("execute.rs")),
    ("src/runner/records.rs", include_str!("records.rs")),
    ("src/runner/hardware.rs", include_str!("hardware.rs")),
    ("src/runner/series.rs", include_str!("series.rs")),
    ("src/runner/job.rs", include_str!("job.rs")),
    ("src/runner/longterm.rs", include_str!("longterm.rs")),
    ("src/runner/studies.rs", include_str!("studies.rs")),
    ("src/runner/events.rs", include_str!("events.rs")),
];

#[test]
fn the_runner_builds_no_json_bags() {
    let mut found = vec![];
    for (path, text) in RUNNER.iter() {
        for (i, line) in text.lines().enumerate() {
            let l = line.trim_start();
            if l.starts_with("mod tests") {
                break; // the files' own tests compare with literal documents
            }
            if l.starts_with("//") {
                continue;
            }
            if l.contains(concat!("json", "!(")) {
                found.push(format!("{path}:{}: {}", i + 1, line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "a document built as a JSON bag in the runner (build it from its type):\n{}",
        found.join("\n")
    );
}
