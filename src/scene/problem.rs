//! What is wrong with a document: each problem with the JSON pointer (RFC 6901) of the
//! field at fault and a plain message.

use serde::Serialize;

/// One problem found in a document.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Problem {
    /// JSON pointer of the offending field, e.g. `/objects/1/transform/2/matrix`.
    pub pointer: String,
    /// What is wrong, in plain words.
    pub message: String,
}

impl Problem {
    /// A problem at `pointer`.
    pub fn new(pointer: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            pointer: pointer.into(),
            message: message.into(),
        }
    }
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let at = if self.pointer.is_empty() {
            "(document)"
        } else {
            &self.pointer
        };
        write!(f, "{at}: {}", self.message)
    }
}

/// Why a document was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// The bytes are not JSON.
    #[error("the scene is not valid JSON: {message} at line {line}, column {column}")]
    Syntax {
        /// serde_json's reason.
        message: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
    },
    /// JSON, but not a valid scene: every problem found.
    #[error("the scene is invalid: {}", summary(.0))]
    Invalid(Vec<Problem>),
}

impl SceneError {
    /// The problems, if the document was JSON.
    pub fn problems(&self) -> &[Problem] {
        match self {
            SceneError::Invalid(p) => p,
            SceneError::Syntax { .. } => &[],
        }
    }
}

fn summary(p: &[Problem]) -> String {
    match p {
        [one] => one.to_string(),
        [first, rest @ ..] => format!("{first} (and {} more)", rest.len()),
        [] => "no problems recorded".into(),
    }
}

/// Builds JSON pointers, escaping `~` and `/` as RFC 6901 says.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Pointer(String);

impl Pointer {
    /// The whole document: `""`.
    pub fn root() -> Self {
        Self(String::new())
    }

    /// This pointer with one more object key.
    pub fn key(&self, k: &str) -> Self {
        Self(format!(
            "{}/{}",
            self.0,
            k.replace('~', "~0").replace('/', "~1")
        ))
    }

    /// This pointer with one more array index.
    pub fn index(&self, i: usize) -> Self {
        Self(format!("{}/{}", self.0, i))
    }

    /// The pointer text.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Extends with the path serde_path_to_error reports.
    pub fn join_path(&self, path: &serde_path_to_error::Path) -> Self {
        use serde_path_to_error::Segment;
        let mut p = self.clone();
        for seg in path.iter() {
            p = match seg {
                Segment::Seq { index } => p.index(*index),
                Segment::Map { key } => p.key(key),
                Segment::Enum { variant } => p.key(variant),
                Segment::Unknown => p,
            };
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointers_escape_rfc6901() {
        assert_eq!(
            Pointer::root()
                .key("materials")
                .key("a/b~c")
                .index(2)
                .as_str(),
            "/materials/a~1b~0c/2"
        );
    }
}
