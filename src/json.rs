//! Reading JSON strictly: one document and nothing after it, and when it fails, the
//! field at fault (its path, from `serde_path_to_error`) and serde_json's message
//! without the position it appends, since every caller reports line and column apart.
//! A leaf: it depends on no other module.

use serde::de::DeserializeOwned;

/// serde_json's messages end in "at line 1 column 5"; this is the message without it.
pub fn strip_position(msg: &str) -> String {
    match msg.rfind(" at line ") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}

/// Why a document could not be read.
#[derive(Debug)]
pub struct Failure {
    /// serde_json's error: whether it is syntax ([`serde_json::Error::is_syntax`],
    /// [`serde_json::Error::is_eof`]) or a value of the wrong shape, and where.
    pub error: serde_json::Error,
    /// The field at fault (`scene.objects[0]`), when it is one below the document.
    pub path: Option<String>,
}

impl Failure {
    /// serde_json's message without the position.
    pub fn message(&self) -> String {
        strip_position(&self.error.to_string())
    }
}

/// Reads `bytes` as one `T`; anything but white space after it is an error.
pub fn from_slice<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, Failure> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let value = serde_path_to_error::deserialize::<_, T>(&mut de).map_err(|e| {
        let path = e.path().to_string();
        Failure {
            error: e.into_inner(),
            path: (!path.is_empty() && path != ".").then_some(path),
        }
    })?;
    de.end().map_err(|error| Failure { error, path: None })?;
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Doc {
        #[allow(dead_code)]
        inner: Inner,
    }

    #[derive(Debug, serde::Deserialize)]
    struct Inner {
        #[allow(dead_code)]
        n: u8,
    }

    #[test]
    fn the_position_is_cut_from_the_message() {
        assert_eq!(
            strip_position("expected value at line 1 column 5"),
            "expected value"
        );
        assert_eq!(strip_position("no position"), "no position");
    }

    #[test]
    fn failures_name_the_field_and_keep_the_position_apart() {
        let f = from_slice::<Doc>(br#"{"inner": {"n": 300}}"#).unwrap_err();
        assert_eq!(f.path.as_deref(), Some("inner.n"));
        assert!(!f.error.is_syntax());
        assert_eq!(f.message(), "invalid value: integer `300`, expected u8");
        let f = from_slice::<Doc>(br#"{"inner": {"n": 3}} x"#).unwrap_err();
        assert_eq!((f.path, f.error.is_syntax()), (None, true));
        assert_eq!((f.error.line(), f.error.column()), (1, 21));
        let f = from_slice::<Doc>(b"[").unwrap_err();
        assert!(f.error.is_eof() || f.error.is_syntax());
        let f = from_slice::<Doc>(br#"{"other": 1}"#).unwrap_err();
        assert_eq!(f.path.as_deref(), Some("other"));
        assert!(f.message().starts_with("unknown field `other`"));
        assert!(from_slice::<Doc>(b" {\"inner\": {\"n\": 3}}\n").is_ok());
    }
}
