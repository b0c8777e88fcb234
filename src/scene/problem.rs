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

/// A JSON pointer (RFC 6901, `~` and `/` escaped), built lazily: a step keeps its
/// parent by reference, and the text is written only when it is asked for, when a
/// problem is reported. So checking a valid document, which passes a pointer to every
/// check of every object, builds no strings.
#[derive(Debug, Clone)]
pub struct Pointer<'a>(Step<'a>);

#[derive(Debug, Clone)]
enum Step<'a> {
    /// A whole pointer, as text (the root is empty).
    Text(String),
    /// An object key below a pointer.
    Key(&'a Pointer<'a>, &'a str),
    /// An array index below a pointer.
    Index(&'a Pointer<'a>, usize),
}

impl Default for Pointer<'_> {
    fn default() -> Self {
        Pointer(Step::Text(String::new()))
    }
}

impl Pointer<'_> {
    /// The whole document: `""`.
    pub fn root() -> Pointer<'static> {
        Pointer::default()
    }

    /// This pointer with one more object key.
    pub fn key<'b>(&'b self, k: &'b str) -> Pointer<'b> {
        Pointer(Step::Key(self, k))
    }

    /// This pointer with one more array index.
    pub fn index(&self, i: usize) -> Pointer<'_> {
        Pointer(Step::Index(self, i))
    }

    /// The same pointer, holding its own text.
    pub fn owned(&self) -> Pointer<'static> {
        Pointer(Step::Text(self.to_string()))
    }

    /// Extends with the path serde_path_to_error reports.
    pub fn join_path(&self, path: &serde_path_to_error::Path) -> Pointer<'static> {
        use serde_path_to_error::Segment;
        let mut p = self.owned();
        for seg in path.iter() {
            p = match seg {
                Segment::Seq { index } => p.index(*index).owned(),
                Segment::Map { key } => p.key(key).owned(),
                Segment::Enum { variant } => p.key(variant).owned(),
                Segment::Unknown => p,
            };
        }
        p
    }
}

/// The pointer text.
impl std::fmt::Display for Pointer<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            Step::Text(t) => f.write_str(t),
            Step::Key(parent, k) => {
                write!(f, "{parent}/")?;
                for part in k.split_inclusive(['~', '/']) {
                    match part.strip_suffix('~') {
                        Some(rest) => write!(f, "{rest}~0")?,
                        None => match part.strip_suffix('/') {
                            Some(rest) => write!(f, "{rest}~1")?,
                            None => f.write_str(part)?,
                        },
                    }
                }
                Ok(())
            }
            Step::Index(parent, i) => write!(f, "{parent}/{i}"),
        }
    }
}

/// Pointers are equal when their texts are.
impl PartialEq for Pointer<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.to_string() == other.to_string()
    }
}

impl Eq for Pointer<'_> {}

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
                .to_string(),
            "/materials/a~1b~0c/2"
        );
        let root = Pointer::root();
        let first = root.key("~1/");
        let second = first.key("");
        let odd = second.key("/~");
        assert_eq!(odd.to_string(), "/~01~1//~1~0");
        assert_eq!(odd.owned(), odd);
        assert_eq!(odd.owned().index(0).to_string(), "/~01~1//~1~0/0");
        assert_eq!(Pointer::root().to_string(), "");
    }
}
