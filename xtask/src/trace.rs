//! `cargo xtask trace`: the traceability matrix, requirement → tests → result, and its gate.
//!
//! The requirements are listed in `requirements/*.toml` (schema in `requirements/README.md`).
//! The results come from running the tests: nextest's JUnit report
//! (`cargo nextest run --profile ci`, `.config/nextest.toml`). A test verifies the requirement
//! its name starts with (`en50325_5_7_1_2_…` → EN 50325-5 7.1.2, `cia304_9_5_…`,
//! `cia301_table2_…`, `sc_req_05_…`, `iec61784_3_loss_…`; several joined by `_and_`), and every
//! requirement that lists it under `tests`. The matrix is written to `docs/traceability.md`
//! (committed, so that it reads without a build; `cargo xtask test` fails when the committed
//! one is not the one its run writes) and `target/traceability/traceability.html` (an artefact
//! of the run).
//!
//! The gate fails, with one sentence per problem, when a test fails, when a test names a
//! requirement that is not listed (or names a standard but no clause, and no requirement lists
//! it), when a requirement lists a test that did not run, and when a requirement meant to be
//! verified by test on the device or the tool has no test that ran, unless it is marked
//! `status = "planned"` (those are listed as not yet implemented).

mod report;

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// How a standard's clause is written in a test name after its prefix.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Form {
    /// Clause numbers (`7_1_2` → 7.1.2) or a table (`table5` → Table 5).
    Clause,
    /// A requirement number (`05` → SC_REQ_05).
    Number,
    /// An IEC 61784-3 communication error class (`loss` → IEC 61784-3 loss).
    ErrorClass,
    /// No clause in the name: a requirement must list the test under `tests`.
    Bare,
}

/// Test name prefixes, how their requirement identifier starts, and how the clause follows.
const STANDARDS: [(&str, &str, Form); 6] = [
    ("en50325_5_", "EN 50325-5", Form::Clause),
    ("cia304_", "CiA 304", Form::Clause),
    ("cia301_", "CiA 301", Form::Clause),
    ("sc_req_", "SC_REQ_", Form::Number),
    ("iec61784_3_", "IEC 61784-3", Form::ErrorClass),
    ("iso11898_1_", "ISO 11898-1", Form::Bare),
];

/// The communication error classes of IEC 61784-3, as EN 50325-5 Table 1 lists them.
const ERROR_CLASSES: [&str; 8] = [
    "corruption",
    "repetition",
    "sequence",
    "loss",
    "delay",
    "insertion",
    "masquerade",
    "addressing",
];

/// What a test name says it verifies.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Named {
    /// A requirement identifier, e.g. `EN 50325-5 7.1.2`.
    Requirement(String),
    /// A standard without a clause, e.g. `CiA 301` for `cia301_data_length_…`.
    StandardOnly(&'static str),
}

/// What the start of `name` (from `name`'s first `_`-separated part on) says it verifies, and
/// the parts after it.
fn named_at<'a>(parts: &'a [&'a str]) -> Option<(Named, &'a [&'a str])> {
    let joined = parts.join("_");
    let (prefix, standard, form) = STANDARDS
        .iter()
        .find(|(prefix, _, _)| format!("{joined}_").starts_with(prefix))?;
    let skip = prefix.matches('_').count();
    let rest = parts.get(skip..).unwrap_or(&[]);
    let is_number = |part: &&str| !part.is_empty() && part.chars().all(|c| c.is_ascii_digit());
    match form {
        Form::Number => match rest.first() {
            Some(number) if is_number(number) => Some((
                Named::Requirement(format!("{standard}{number}")),
                &rest[1..],
            )),
            _ => Some((Named::StandardOnly(standard), rest)),
        },
        Form::ErrorClass => match rest.first() {
            Some(class) if ERROR_CLASSES.contains(class) => Some((
                Named::Requirement(format!("{standard} {class}")),
                &rest[1..],
            )),
            _ => Some((Named::StandardOnly(standard), rest)),
        },
        Form::Bare => Some((Named::StandardOnly(standard), rest)),
        Form::Clause => {
            if let Some(table) = rest.first().and_then(|part| part.strip_prefix("table"))
                && is_number(&table)
            {
                return Some((
                    Named::Requirement(format!("{standard} Table {table}")),
                    &rest[1..],
                ));
            }
            let count = rest.iter().take_while(|part| is_number(part)).count();
            if count == 0 {
                return Some((Named::StandardOnly(standard), rest));
            }
            let clause = rest[..count].join(".");
            Some((
                Named::Requirement(format!("{standard} {clause}")),
                &rest[count..],
            ))
        }
    }
}

/// What a test name says it verifies: its leading clause, and further ones joined by `_and_`
/// (`cia304_9_5_and_en50325_5_7_1_1_…` → CiA 304 9.5, EN 50325-5 7.1.1). Empty for a name that
/// starts with no known prefix.
pub fn named(name: &str) -> Vec<Named> {
    let parts: Vec<&str> = name.split('_').collect();
    let mut found = Vec::new();
    let mut at: &[&str] = &parts;
    while let Some((one, rest)) = named_at(at) {
        let standard_only = matches!(one, Named::StandardOnly(_));
        found.push(one);
        match rest.split_first() {
            Some((&"and", next)) if !standard_only => at = next,
            _ => break,
        }
    }
    found
}

/// How a requirement is verified.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Verification {
    /// By an automated test; the gate requires one.
    Test,
    /// By an analysis (a document or calculation).
    Analysis,
    /// By a review (of design, documents or process).
    Review,
}

/// Whom a requirement binds.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, PartialOrd, Ord)]
#[serde(rename_all = "kebab-case")]
pub enum Applicability {
    /// The device (its firmware or hardware).
    Device,
    /// The configuration tool.
    Tool,
    /// Whoever builds the safety system from devices.
    SystemIntegrator,
    /// Nobody here; `reason` says why.
    NotApplicable,
}

/// Whether the implementation exists.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// It exists; a test-verified requirement must have a test.
    #[default]
    Implemented,
    /// Not yet implemented: listed, not gated.
    Planned,
}

/// One `[[requirement]]` entry as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    id: String,
    title: Option<String>,
    source_status: Option<String>,
    statement: String,
    verification: Verification,
    applicability: Vec<Applicability>,
    #[serde(default)]
    status: Status,
    reason: Option<String>,
    implemented_in: Vec<String>,
    #[serde(default)]
    tests: Vec<String>,
    note: Option<String>,
}

/// A `[document]` table: what the file's requirements come from.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DocumentEntry {
    title: String,
    source: String,
}

/// One requirements file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileEntry {
    document: DocumentEntry,
    requirement: Vec<toml::Spanned<Entry>>,
}

/// A requirement, checked, with where it is written.
#[derive(Debug)]
pub struct Requirement {
    /// Its identifier, e.g. `EN 50325-5 7.1.2` or `SC_REQ_05`.
    pub id: String,
    /// The source's own title (SimpleCAN), if it has one.
    pub title: Option<String>,
    /// The status the source list itself gives (SimpleCAN), if any.
    pub source_status: Option<String>,
    /// One line in our words.
    pub statement: String,
    /// How it is verified.
    pub verification: Verification,
    /// Whom it binds.
    pub applicability: Vec<Applicability>,
    /// Whether it is implemented.
    pub status: Status,
    /// Why it does not apply (required for not-applicable).
    pub reason: Option<String>,
    /// Module paths or documents where it is implemented.
    pub implemented_in: Vec<String>,
    /// Tests that verify it besides those named after it (function names).
    pub tests: Vec<String>,
    /// A remark for the reader.
    pub note: Option<String>,
    /// The file it is written in, as given to the loader.
    pub file: String,
    /// The line its entry starts on.
    pub line: usize,
}

impl Requirement {
    /// Whether the gate requires a test for it: verified by test, binding the device or the
    /// tool, and implemented.
    pub fn needs_test(&self) -> bool {
        self.verification == Verification::Test
            && self.status == Status::Implemented
            && self
                .applicability
                .iter()
                .any(|a| matches!(a, Applicability::Device | Applicability::Tool))
    }
}

/// The requirements of one file, and what they come from.
#[derive(Debug)]
pub struct Document {
    /// The file, as given to the loader (e.g. `requirements/cia304.toml`).
    pub file: String,
    /// The standard or list.
    pub title: String,
    /// Where its text is.
    pub source: String,
    /// Its requirements, in the file's order.
    pub requirements: Vec<Requirement>,
}

/// The line (from 1) that byte `offset` of `text` is on.
fn line_of(text: &str, offset: usize) -> usize {
    text.get(..offset)
        .map_or(0, |before| before.matches('\n').count())
        + 1
}

/// Parses one requirements file; `file` names it in every error.
pub fn parse_file(file: &str, text: &str) -> Result<Document> {
    let parsed: FileEntry = toml::from_str(text).map_err(|error| {
        // toml's message starts with the line and column and quotes the line.
        anyhow::anyhow!("{file}: {error}")
    })?;
    let mut requirements = Vec::new();
    for spanned in parsed.requirement {
        let line = line_of(text, spanned.span().start);
        let entry = spanned.into_inner();
        let at = format!("{file}:{line}: requirement `{}`", entry.id);
        if entry.id.trim().is_empty() || entry.id.trim() != entry.id {
            bail!("{at}: the identifier is empty or has spaces around it");
        }
        if entry.statement.trim().is_empty() || entry.statement.contains('\n') {
            bail!("{at}: the statement must be one non-empty line");
        }
        if entry.applicability.is_empty() {
            bail!("{at}: applicability is empty; name whom it binds, or not-applicable");
        }
        let not_applicable = entry.applicability.contains(&Applicability::NotApplicable);
        if not_applicable && entry.applicability.len() > 1 {
            bail!("{at}: not-applicable cannot be combined with another applicability");
        }
        if not_applicable && entry.reason.as_deref().is_none_or(|r| r.trim().is_empty()) {
            bail!("{at}: a not-applicable requirement needs its reason (`reason = \"…\"`)");
        }
        if let Some(test) = entry.tests.iter().find(|t| t.contains(char::is_whitespace)) {
            bail!("{at}: `{test}` in tests is not a test function name");
        }
        requirements.push(Requirement {
            id: entry.id,
            title: entry.title,
            source_status: entry.source_status,
            statement: entry.statement,
            verification: entry.verification,
            applicability: entry.applicability,
            status: entry.status,
            reason: entry.reason,
            implemented_in: entry.implemented_in,
            tests: entry.tests,
            note: entry.note,
            file: file.to_owned(),
            line,
        });
    }
    Ok(Document {
        file: file.to_owned(),
        title: parsed.document.title,
        source: parsed.document.source,
        requirements,
    })
}

/// Loads every `*.toml` in `dir` (in name order), refusing an identifier listed twice.
pub fn load(root: &Path, dir: &Path) -> Result<Vec<Document>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the requirements in {}", dir.display()))?
        .filter_map(|entry| entry.ok().map(|entry| entry.path()))
        .filter(|path| path.extension().is_some_and(|ext| ext == "toml"))
        .collect();
    paths.sort();
    let mut documents = Vec::new();
    let mut seen: BTreeMap<String, String> = BTreeMap::new();
    for path in paths {
        let shown = path
            .strip_prefix(root)
            .unwrap_or(&path)
            .display()
            .to_string();
        let text =
            std::fs::read_to_string(&path).with_context(|| format!("cannot read {shown}"))?;
        let document = parse_file(&shown, &text)?;
        for requirement in &document.requirements {
            let here = format!("{}:{}", requirement.file, requirement.line);
            if let Some(first) = seen.insert(requirement.id.clone(), here.clone()) {
                bail!(
                    "{here}: requirement `{}` is already listed at {first}",
                    requirement.id
                );
            }
        }
        documents.push(document);
    }
    if documents.is_empty() {
        bail!("no requirements files (*.toml) in {}", dir.display());
    }
    Ok(documents)
}

/// The result of one test in the JUnit report.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// It passed.
    Passed,
    /// It failed; the first line of its message.
    Failed(String),
    /// It did not run (ignored or filtered).
    Skipped,
}

/// One test case of the JUnit report.
#[derive(Clone, Debug)]
pub struct TestCase {
    /// The test binary (`shared`, `system-tests::dual_channel`).
    pub binary: String,
    /// The test's path in its binary (`node::tests::cia301_7_3_2_…`).
    pub path: String,
    /// Its result.
    pub outcome: Outcome,
}

impl TestCase {
    /// The test function's name: the last segment of its path.
    pub fn function(&self) -> &str {
        self.path.rsplit("::").next().unwrap_or(&self.path)
    }

    /// Binary and path, as the matrix shows them.
    pub fn shown(&self) -> String {
        format!("{} {}", self.binary, self.path)
    }
}

/// Reads nextest's JUnit report (`<testcase name classname>` with `<failure>`, `<error>` or
/// `<skipped>` children), sorted by binary and path: nextest writes them in the order they
/// finished, and the matrix must not change with that.
pub fn parse_junit(xml: &str) -> Result<Vec<TestCase>> {
    let document = roxmltree::Document::parse(xml).context("the JUnit report is not XML")?;
    let mut cases = Vec::new();
    for node in document
        .descendants()
        .filter(|n| n.has_tag_name("testcase"))
    {
        let attribute = |name: &str| {
            node.attribute(name).map(str::to_owned).with_context(|| {
                format!("a <testcase> of the JUnit report has no `{name}` attribute")
            })
        };
        let failure = node
            .children()
            .find(|c| c.has_tag_name("failure") || c.has_tag_name("error"));
        let outcome = if let Some(failure) = failure {
            let message = failure
                .attribute("message")
                .or_else(|| failure.text())
                .unwrap_or("no message")
                .lines()
                .next()
                .unwrap_or("no message")
                .to_owned();
            Outcome::Failed(message)
        } else if node.children().any(|c| c.has_tag_name("skipped")) {
            Outcome::Skipped
        } else {
            Outcome::Passed
        };
        cases.push(TestCase {
            binary: attribute("classname")?,
            path: attribute("name")?,
            outcome,
        });
    }
    cases.sort_by(|a, b| (&a.binary, &a.path).cmp(&(&b.binary, &b.path)));
    Ok(cases)
}

/// A requirement's result in the matrix.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Every test that verifies it ran and passed.
    Pass,
    /// At least one of its tests failed.
    Fail,
    /// It has tests, but none of them ran.
    NotRun,
    /// Meant to be verified by test, implemented, and no test verifies it.
    NoTest,
    /// Marked planned: not yet implemented.
    NotYetImplemented,
    /// Verified by analysis, outside this matrix.
    ByAnalysis,
    /// Verified by review, outside this matrix.
    ByReview,
    /// Binds only the system integrator: stated for the safety manual.
    SystemIntegrator,
    /// Does not apply; the reason is given.
    NotApplicable,
}

impl Verdict {
    /// The word the matrix shows.
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Pass => "PASS",
            Verdict::Fail => "FAIL",
            Verdict::NotRun => "NOT RUN",
            Verdict::NoTest => "NO TEST",
            Verdict::NotYetImplemented => "NOT YET IMPLEMENTED",
            Verdict::ByAnalysis => "by analysis",
            Verdict::ByReview => "by review",
            Verdict::SystemIntegrator => "system integrator",
            Verdict::NotApplicable => "N/A",
        }
    }
}

/// The matrix: each requirement with the tests that verify it, the results, and the problems.
#[derive(Debug)]
pub struct Matrix<'a> {
    /// The requirements files.
    pub documents: &'a [Document],
    /// Every test of the run.
    pub tests: &'a [TestCase],
    /// Per requirement identifier, the indices (into `tests`) of the tests that verify it.
    pub verified_by: BTreeMap<&'a str, BTreeSet<usize>>,
    /// Indices of tests that verify no requirement.
    pub untraced: Vec<usize>,
    /// One sentence per problem; the gate fails when there is any.
    pub problems: Vec<String>,
}

impl<'a> Matrix<'a> {
    /// Maps the tests to the requirements and judges the result.
    pub fn build(documents: &'a [Document], tests: &'a [TestCase]) -> Self {
        let requirements: Vec<&Requirement> =
            documents.iter().flat_map(|d| &d.requirements).collect();
        let known: BTreeSet<&str> = requirements.iter().map(|r| r.id.as_str()).collect();
        let listed: BTreeSet<&str> = requirements
            .iter()
            .flat_map(|r| r.tests.iter().map(String::as_str))
            .collect();
        let mut verified_by: BTreeMap<&str, BTreeSet<usize>> = BTreeMap::new();
        let mut problems = Vec::new();
        for (index, test) in tests.iter().enumerate() {
            for named in named(test.function()) {
                match named {
                    Named::Requirement(id) => match known.get(id.as_str()) {
                        Some(id) => {
                            verified_by.entry(id).or_default().insert(index);
                        }
                        None => problems.push(format!(
                            "Test `{}` names requirement `{id}`, which no requirements file \
                             lists: add it to requirements/ or correct the name.",
                            test.shown()
                        )),
                    },
                    Named::StandardOnly(standard) if !listed.contains(test.function()) => {
                        problems.push(format!(
                            "Test `{}` names {standard} but no clause, and no requirement lists \
                             it under `tests`: name the clause or list the test.",
                            test.shown()
                        ));
                    }
                    Named::StandardOnly(_) => {}
                }
            }
        }
        for requirement in &requirements {
            for function in &requirement.tests {
                let matching: Vec<usize> = tests
                    .iter()
                    .enumerate()
                    .filter(|(_, t)| t.function() == function)
                    .map(|(index, _)| index)
                    .collect();
                if matching.is_empty() {
                    problems.push(format!(
                        "Requirement `{}` ({}:{}) lists test `{function}`, which is not among the \
                         tests that ran.",
                        requirement.id, requirement.file, requirement.line
                    ));
                }
                verified_by
                    .entry(requirement.id.as_str())
                    .or_default()
                    .extend(matching);
            }
        }
        for test in tests {
            if let Outcome::Failed(message) = &test.outcome {
                problems.push(format!("Test `{}` failed: {message}", test.shown()));
            }
        }
        let mut matrix = Matrix {
            documents,
            tests,
            untraced: Vec::new(),
            verified_by,
            problems,
        };
        for requirement in &requirements {
            match matrix.verdict(requirement) {
                Verdict::NoTest => matrix.problems.push(format!(
                    "Requirement `{}` ({}:{}) is to be verified by test, but no test verifies it: \
                     name a test after it, list one under `tests`, or mark it \
                     `status = \"planned\"`.",
                    requirement.id, requirement.file, requirement.line
                )),
                Verdict::NotRun if requirement.needs_test() => matrix.problems.push(format!(
                    "Requirement `{}` ({}:{}) is to be verified by test, but none of its tests ran.",
                    requirement.id, requirement.file, requirement.line
                )),
                _ => {}
            }
        }
        let traced: BTreeSet<usize> = matrix.verified_by.values().flatten().copied().collect();
        matrix.untraced = (0..tests.len()).filter(|i| !traced.contains(i)).collect();
        matrix
    }

    /// The tests that verify `requirement`.
    pub fn tests_of(&self, requirement: &Requirement) -> Vec<&'a TestCase> {
        self.verified_by
            .get(requirement.id.as_str())
            .map(|set| set.iter().map(|&i| &self.tests[i]).collect())
            .unwrap_or_default()
    }

    /// `requirement`'s result.
    pub fn verdict(&self, requirement: &Requirement) -> Verdict {
        let tests = self.tests_of(requirement);
        if requirement.applicability == [Applicability::NotApplicable] {
            return Verdict::NotApplicable;
        }
        if requirement.status == Status::Planned {
            return Verdict::NotYetImplemented;
        }
        if requirement.applicability == [Applicability::SystemIntegrator] {
            return Verdict::SystemIntegrator;
        }
        match requirement.verification {
            Verification::Analysis => return Verdict::ByAnalysis,
            Verification::Review => return Verdict::ByReview,
            Verification::Test => {}
        }
        if tests.is_empty() {
            return Verdict::NoTest;
        }
        if tests
            .iter()
            .any(|t| matches!(t.outcome, Outcome::Failed(_)))
        {
            Verdict::Fail
        } else if tests.iter().all(|t| t.outcome == Outcome::Skipped) {
            Verdict::NotRun
        } else {
            Verdict::Pass
        }
    }
}

/// Where nextest writes the `ci` profile's JUnit report (`.config/nextest.toml`).
fn junit_path(root: &Path) -> PathBuf {
    let target =
        std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), PathBuf::from);
    target.join("nextest/ci/junit.xml")
}

/// Installs cargo-nextest from crates.io when `cargo nextest` is missing.
pub fn ensure_nextest() -> Result<()> {
    let installed = crate::cargo()
        .args(["nextest", "--version"])
        .output()
        .is_ok_and(|output| output.status.success());
    if installed {
        eprintln!("xtask: cargo-nextest: installed");
        return Ok(());
    }
    eprintln!(
        "xtask: installing cargo-nextest from crates.io (a source build: about 12 minutes of CPU)"
    );
    crate::run(crate::cargo().args(["install", "cargo-nextest", "--locked"]))
}

/// Runs every workspace test with nextest's `ci` profile, which writes the JUnit report the
/// matrix is built from. Returns whether every test passed; a run that could not produce the
/// report (a build error) is an error.
pub fn run_tests(root: &Path) -> Result<bool> {
    ensure_nextest()?;
    let junit = junit_path(root);
    // A report left by an earlier run must never stand in for this one.
    if junit.exists() {
        std::fs::remove_file(&junit)
            .with_context(|| format!("cannot remove the old {}", junit.display()))?;
    }
    let status = crate::cargo()
        .args(["nextest", "run", "--workspace", "--profile", "ci"])
        .status()?;
    if !junit.exists() {
        bail!(
            "the test run ({status}) wrote no JUnit report; it did not get as far as running tests"
        );
    }
    Ok(status.success())
}

/// Where the matrix is committed, from the workspace root.
const MATRIX: &str = "docs/traceability.md";

/// Builds the matrix from the requirements and the JUnit report the last `run_tests` wrote,
/// writes it, and fails with one sentence per problem. With `check` (`cargo xtask test`), it
/// also fails when the matrix differs from the committed one, naming the lines that differ;
/// the fresh matrix is written all the same, to be committed.
pub fn report(root: &Path, check: bool) -> Result<()> {
    let documents = load(root, &root.join("requirements"))?;
    let junit = junit_path(root);
    let xml = std::fs::read_to_string(&junit).with_context(|| {
        format!(
            "no JUnit report at {}: run the tests first",
            junit.display()
        )
    })?;
    let tests = parse_junit(&xml)?;
    let matrix = Matrix::build(&documents, &tests);
    let markdown = report::markdown(&matrix);
    let committed = check.then(|| crate::generated::committed(root, MATRIX));
    std::fs::create_dir_all(root.join("docs"))?;
    std::fs::write(root.join(MATRIX), &markdown)?;
    let html_dir = junit
        .parent()
        .and_then(Path::parent)
        .and_then(Path::parent)
        .map_or_else(|| root.join("target"), Path::to_path_buf)
        .join("traceability");
    std::fs::create_dir_all(&html_dir)?;
    let html = html_dir.join("traceability.html");
    std::fs::write(&html, report::html(&matrix))?;
    let counts = report::counts(&matrix);
    println!(
        "xtask: traceability: {} requirements ({}), {} of {} tests trace to one: \
         docs/traceability.md, {}",
        counts.iter().map(|(_, n)| n).sum::<usize>(),
        report::summary(&counts),
        tests.len() - matrix.untraced.len(),
        tests.len(),
        html.display()
    );
    if !matrix.problems.is_empty() {
        for problem in &matrix.problems {
            eprintln!("xtask: traceability: {problem}");
        }
        bail!(
            "the traceability gate found {} problem(s), listed above and in docs/traceability.md",
            matrix.problems.len()
        );
    }
    match committed {
        Some(None) => {
            bail!("{MATRIX} is not committed: the fresh matrix is written there, commit it")
        }
        Some(Some(committed)) => {
            if let Some(difference) = crate::generated::difference(&committed, &markdown) {
                bail!(
                    "the committed {MATRIX} is not the matrix of this run, {difference}\n\
                     The fresh matrix is written to {MATRIX}: commit it (`cargo xtask trace \
                     --report-only` writes it again from this run's JUnit report)."
                );
            }
            println!("xtask: traceability: the committed {MATRIX} is this run's matrix");
        }
        None => {}
    }
    Ok(())
}

/// `cargo xtask trace`: run the tests (unless `report_only`), then write and check the matrix,
/// and with `check` that the committed one is the one written.
pub fn task(root: &Path, report_only: bool, check: bool) -> Result<()> {
    if report_only {
        return report(root, check);
    }
    crate::toolchain::ensure_tshark()?;
    let passed = run_tests(root)?;
    report(root, check)?;
    if !passed {
        bail!("the test run failed");
    }
    Ok(())
}

#[cfg(test)]
mod tests;
