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
