//! The project's own files (README, docs, sources, tests, examples, scripts, CI) describe what
//! the crate does; how it was developed belongs to git. This guard fails on the words that
//! speak of the development itself: numbered work steps, references to tickets, figures
//! dated by the day they were measured, and paths of a developer's machine.

use std::path::{Path, PathBuf};

use crate::common::repo_path;

/// Phrases that only speak of the development (matched in lower case, with the `|` that
/// splits some of them removed: so spelled, this file does not itself name what it forbids).
const PHRASES: &[&str] = &[
    "to|day's",
    "to|day,",
    "to|day)",
    "the issue",
    "lent machine",
    "plumenet|-work",
    "this ses|sion",
    "earlier ses|sion",
    "previous ses|sion",
    "next ses|sion",
    "/ro|ot/",
    "/work|/main",
    "before this setting",
    "records from before",
    "any-room change",
];

/// Words that speak of the development when a number follows them ("step 3" is fine, the
/// names of work units are not).
const NUMBERED: &[&str] = &["stop", "stops", "issue", "issues", "session", "sessions"];

/// Every text file of the project that a user reads or builds.
fn project_files() -> Vec<PathBuf> {
    let mut files = vec![
        repo_path("README.md"),
        repo_path("Cargo.toml"),
        repo_path(".ci/run"),
    ];
    for dir in [
        "docs",
        "src",
        "tests",
        "examples",
        "scripts",
        "data/layouts",
    ] {
        collect(&repo_path(dir), &mut files);
    }
    files
}

fn collect(dir: &Path, files: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            collect(&path, files);
        } else if matches!(
            path.extension().and_then(|e| e.to_str()),
            Some("rs" | "md" | "py" | "html" | "json" | "toml")
        ) {
            files.push(path);
        }
    }
}

/// The offending phrases of one text, with their line numbers.
fn offences(text: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let lower = line.to_lowercase();
        for phrase in PHRASES {
            let phrase = phrase.replace('|', "");
            if lower.contains(&phrase) {
                found.push((n + 1, phrase));
            }
        }
        for word in NUMBERED {
            for (at, _) in lower.match_indices(word) {
                let before = lower[..at].chars().next_back();
                let after = &lower[at + word.len()..];
                let starts_word = !before.is_some_and(char::is_alphanumeric);
                let numbered = after
                    .strip_prefix(' ')
                    .and_then(|rest| rest.chars().next())
                    .is_some_and(|c| c.is_ascii_digit());
                if starts_word && numbered {
                    let number = after[1..].split(' ').next().unwrap_or("");
                    found.push((n + 1, format!("{word} {number}")));
                }
            }
        }
    }
    found
}

#[test]
fn the_guard_catches_what_it_should_and_spares_the_domain() {
    // Probes spelled with a `|` that is removed before they are checked (see PHRASES).
    let probe = |text: &str| offences(&text.replace('|', "")).len();
    assert_eq!(probe("measured at st|op 37"), 1);
    assert_eq!(probe("since st|ops 33-39"), 1);
    assert_eq!(probe("as Iss|ue 14 asked"), 1);
    assert_eq!(probe("To|day's default"), 1);
    assert_eq!(probe("in $HOME/plumenet|-work/models"), 1);
    assert_eq!(
        offences("what records from before this setting read back as").len(),
        2
    );
    // The crate's own vocabulary: a live session, a robot that stops, steps of a scheme.
    assert!(offences("a live session over TCP; stop-sense-go stops every metre").is_empty());
    assert!(offences("the session's state file; 3 steps of the solver").is_empty());
    assert!(offences("let config = c.session(1);").is_empty());
}

#[test]
fn project_files_do_not_speak_of_the_development() {
    let this = repo_path(file!());
    let mut report = Vec::new();
    for path in project_files() {
        if path.ends_with("tests/project_files.rs") || path == this {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(&path) else {
            continue;
        };
        for (line, phrase) in offences(&text) {
            let rel = path.strip_prefix(repo_path("")).unwrap_or(&path);
            report.push(format!("{}:{line}: {phrase:?}", rel.display()));
        }
    }
    assert!(
        report.is_empty(),
        "development words in the project's files:\n{}",
        report.join("\n")
    );
}

/// The README is for users: short, and its first screen says how to run the main job, how to
/// use one's own room and what accuracy to expect.
#[test]
fn the_readme_is_short_and_its_first_screen_answers_a_newcomer() {
    let readme = std::fs::read_to_string(repo_path("README.md")).unwrap();
    let lines: Vec<&str> = readme.lines().collect();
    assert!(lines.len() <= 420, "README has {} lines", lines.len());
    let first = lines[..60.min(lines.len())].join("\n");
    for needle in [
        "cargo run --release --locked -- localize",
        "cargo test --release --locked",
        "## What to expect",
        "highest reading",
        "your own room",
    ] {
        assert!(
            first.contains(needle),
            "the README's first 60 lines lack {needle:?}"
        );
    }
    // Every document it links to exists.
    for doc in [
        "method",
        "plumenet",
        "robustness",
        "performance",
        "robot",
        "ablations",
    ] {
        let rel = format!("docs/{doc}.md");
        assert!(readme.contains(&rel), "the README does not link {rel}");
        assert!(repo_path(&rel).is_file(), "{rel} is missing");
    }
}

/// One shipped default, and at most one other model (the one-arena baseline that
/// `docs/plumenet.md` evaluates).
#[test]
fn models_holds_the_default_and_at_most_one_other() {
    let models: Vec<String> = std::fs::read_dir(repo_path("models"))
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(models.contains(&"default".to_string()), "{models:?}");
    assert!(models.len() <= 2, "{models:?}");
    let docs = std::fs::read_to_string(repo_path("docs/plumenet.md")).unwrap();
    for model in models.iter().filter(|m| *m != "default") {
        assert!(
            docs.contains(&format!("--model models/{model}")),
            "models/{model} ships but no documented command uses it"
        );
    }
}
