//! A config problem, typed: the field at fault and what is wrong with it. A command-line flag
//! that sets a field reports the problems of that field under its own name, by matching the
//! field, never the message text.

use std::fmt;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigProblem {
    /// The field's dotted path, e.g. `optimizer.lr`.
    pub field: String,
    /// What is wrong, with the accepted values.
    pub message: String,
}

impl ConfigProblem {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }
}

impl fmt::Display for ConfigProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.message)
    }
}

/// Adds a problem for `field` unless `value` is finite and above 0.
pub fn require_positive(problems: &mut Vec<ConfigProblem>, field: &str, value: f64) {
    if !(value.is_finite() && value > 0.0) {
        problems.push(ConfigProblem::new(
            field,
            format!("{value} (accepted: a finite number > 0)"),
        ));
    }
}

/// Adds a problem for `field` unless `value` is finite and at least 0.
pub fn require_non_negative(problems: &mut Vec<ConfigProblem>, field: &str, value: f64) {
    if !(value.is_finite() && value >= 0.0) {
        problems.push(ConfigProblem::new(
            field,
            format!("{value} (accepted: a finite number >= 0)"),
        ));
    }
}

/// Adds a problem for `field` when `value` is 0.
pub fn require_count(problems: &mut Vec<ConfigProblem>, field: &str, value: usize) {
    if value == 0 {
        problems.push(ConfigProblem::new(field, "0 (accepted: an integer >= 1)"));
    }
}

/// The keys of `given` (a config as written) that `known` (the same config read and written
/// back, every field present) does not have, as problems naming each key's dotted path: a
/// config type whose derive cannot deny unknown fields still refuses a misspelt key.
pub fn unknown_keys(given: &serde_json::Value, known: &serde_json::Value) -> Vec<ConfigProblem> {
    let mut problems = Vec::new();
    collect_unknown(given, known, "", &mut problems);
    problems
}

fn collect_unknown(
    given: &serde_json::Value,
    known: &serde_json::Value,
    prefix: &str,
    problems: &mut Vec<ConfigProblem>,
) {
    let (Some(given), Some(known)) = (given.as_object(), known.as_object()) else {
        return;
    };
    for (key, value) in given {
        let path = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        match known.get(key) {
            Some(known_value) => collect_unknown(value, known_value, &path, problems),
            None => {
                let mut fields: Vec<&str> = known.keys().map(String::as_str).collect();
                fields.sort_unstable();
                problems.push(ConfigProblem::new(
                    path,
                    format!("unknown key (accepted here: {})", fields.join(", ")),
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_are_named_by_their_path() {
        let known = serde_json::json!({"name": "a", "render": {"far": 1.0, "near": 0.1}});
        let given = serde_json::json!({"name": "a", "render": {"far": 1.0, "escape_at_fra": true}, "extra": 1});
        let problems = unknown_keys(&given, &known);
        let fields: Vec<&str> = problems.iter().map(|p| p.field.as_str()).collect();
        assert_eq!(fields, vec!["extra", "render.escape_at_fra"]);
        assert!(problems[1].message.contains("far, near"));
        assert!(unknown_keys(&known, &known).is_empty());
    }
}
