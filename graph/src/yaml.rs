//! serde-saphyr's errors in our words: one line, the place as `line L, column C`, and none of
//! the library's advice about its own options (a user cannot set them).

use std::path::Path;

use serde::de::DeserializeOwned;
use serde_saphyr::Location;

/// A YAML document that could not be read or parsed: the file (or origin) and what is wrong,
/// with its line.
#[derive(Debug, thiserror::Error)]
#[error("{origin}: {message}")]
pub struct YamlError {
    pub origin: String,
    pub message: String,
}

/// `text` parsed into `T`, an error naming `origin` and the line at fault.
pub fn from_yaml_str<T: DeserializeOwned>(text: &str, origin: &str) -> Result<T, YamlError> {
    serde_saphyr::from_str(text).map_err(|e| YamlError {
        origin: origin.to_string(),
        message: describe_at(&e, text),
    })
}

/// The YAML file at `path` parsed into `T`: a config file's first step, before its own checks.
pub fn from_yaml_file<T: DeserializeOwned>(path: &Path) -> Result<T, YamlError> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| YamlError {
        origin: origin.clone(),
        message: e.to_string(),
    })?;
    from_yaml_str(&text, &origin)
}

/// What is wrong, without the place (for callers that show the place themselves).
pub fn describe(error: &serde_saphyr::Error) -> String {
    let text = error.to_string();
    let mut message = text.lines().next().unwrap_or_default().trim();
    message = message.strip_prefix("error:").unwrap_or(message).trim();
    // "line 12 column 1: ..." leads the library's message when it knows the place.
    if let Some(rest) = message.strip_prefix("line ")
        && let Some((place, after)) = rest.split_once(": ")
        && place
            .split(" column ")
            .all(|n| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()))
    {
        message = after;
    }
    let message = message.replace(
        ", set DuplicateKeyPolicy in Options if acceptable",
        " (a key may appear once in a mapping)",
    );
    if message.is_empty() {
        "not valid YAML".to_string()
    } else {
        message
    }
}

/// What is wrong and where: `line L, column C: message (in `the line`)`, the line read from
/// `source`, the text that was parsed: the message alone often does not name the key.
pub fn describe_at(error: &serde_saphyr::Error, source: &str) -> String {
    match error.location().filter(|l| *l != Location::UNKNOWN) {
        Some(place) => {
            let line = source
                .lines()
                .nth(place.line().saturating_sub(1) as usize)
                .map(str::trim)
                .filter(|l| !l.is_empty())
                .map(|l| {
                    let shown: String = l.chars().take(80).collect();
                    format!(" (in `{shown}`)")
                })
                .unwrap_or_default();
            format!(
                "line {}, column {}: {}{line}",
                place.line(),
                place.column(),
                describe(error)
            )
        }
        None => describe(error),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn error_of(text: &str) -> serde_saphyr::Error {
        serde_saphyr::from_str::<serde_json::Value>(text).expect_err("invalid YAML")
    }

    #[test]
    fn a_duplicate_key_is_said_in_our_words_with_its_place() {
        let text = "steps: 3\nsteps: 4\n";
        let message = describe_at(&error_of(text), text);
        assert_eq!(
            message,
            "line 2, column 1: duplicate mapping key: steps (a key may appear once in a mapping) (in `steps: 4`)"
        );
        assert!(!message.contains("DuplicateKeyPolicy"));
    }

    #[test]
    fn a_value_of_the_wrong_type_shows_its_line() {
        #[derive(Debug, serde::Deserialize)]
        #[allow(dead_code)]
        struct Config {
            model: String,
            steps: usize,
        }
        let text = "model: tiny\nsteps: ten\n";
        let error = serde_saphyr::from_str::<Config>(text).expect_err("a string for a count");
        let message = describe_at(&error, text);
        assert!(message.starts_with("line 2,"), "{message}");
        assert!(message.contains("`steps: ten`"), "{message}");
    }

    #[test]
    fn a_syntax_error_is_one_line_without_the_library_snippet() {
        let text = "a: [1, 2\nb: 3\n";
        let message = describe_at(&error_of(text), text);
        assert_eq!(message.lines().count(), 1, "{message}");
        assert!(message.starts_with("line "), "{message}");
        assert!(!message.contains("error:"), "{message}");
        assert!(!message.contains("<input>"), "{message}");
    }
}
