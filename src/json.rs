//! Reading JSON strictly: one document and nothing after it, and when it fails, the
//! field at fault (its path, from `serde_path_to_error`) and serde_json's message
//! without the position it appends, since every caller reports line and column apart.
//! A leaf: it depends on no other module.
//!
//! Scenes are read strictly ([`from_slice`]). Hit data may also hold the non-finite
//! numbers Python's `json.dump` writes for a miss (`NaN`, `Infinity`, `-Infinity`):
//! [`from_slice_non_finite`] reads those as strings of the same length, which a field
//! that accepts them turns back into numbers ([`non_finite`]), so every position in an
//! error is still the one in the bytes as sent.
//!
//! [`from_slice`]: crate::json::from_slice
//! [`from_slice_non_finite`]: crate::json::from_slice_non_finite
//! [`non_finite`]: crate::json::non_finite

use std::borrow::Cow;

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

/// The strings [`from_slice_non_finite`] puts in place of the bare words, each as long
/// as the word it replaces (quotes included): `NaN`, `Infinity`, `-Infinity`.
pub const NON_FINITE_STAND_INS: [(&str, f64); 3] = [
    ("N", f64::NAN),
    ("Infini", f64::INFINITY),
    ("-Infini", f64::NEG_INFINITY),
];

/// The number a string means where a number is expected: the stand-ins of
/// [`NON_FINITE_STAND_INS`], and the words themselves, quoted.
pub fn non_finite(s: &str) -> Option<f64> {
    match s {
        "NaN" => Some(f64::NAN),
        "Infinity" => Some(f64::INFINITY),
        "-Infinity" => Some(f64::NEG_INFINITY),
        other => NON_FINITE_STAND_INS
            .iter()
            .find(|(k, _)| *k == other)
            .map(|&(_, x)| x),
    }
}

/// `bytes` with every bare `NaN`, `Infinity` and `-Infinity` outside strings replaced by
/// its stand-in string of the same length; borrowed when there is none.
pub fn quote_non_finite(bytes: &[u8]) -> Cow<'_, [u8]> {
    const WORDS: [&[u8]; 3] = [b"NaN", b"Infinity", b"-Infinity"];
    let mut out: Option<Vec<u8>> = None;
    let (mut in_string, mut escaped) = (false, false);
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        if in_string {
            match (escaped, b) {
                (true, _) => escaped = false,
                (false, b'\\') => escaped = true,
                (false, b'"') => in_string = false,
                _ => {}
            }
            i += 1;
            continue;
        }
        if b == b'"' {
            in_string = true;
            i += 1;
            continue;
        }
        let word = WORDS.iter().position(|w| {
            bytes[i..].starts_with(w)
                && !bytes
                    .get(i + w.len())
                    .is_some_and(|c| c.is_ascii_alphanumeric() || *c == b'_')
        });
        if let Some(k) = word {
            let len = WORDS[k].len();
            let stand_in = format!("\"{}\"", NON_FINITE_STAND_INS[k].0);
            debug_assert_eq!(stand_in.len(), len);
            out.get_or_insert_with(|| bytes.to_vec())[i..i + len]
                .copy_from_slice(stand_in.as_bytes());
            i += len;
            continue;
        }
        i += 1;
    }
    out.map_or(Cow::Borrowed(bytes), Cow::Owned)
}

/// [`from_slice`] for data whose numbers may be `NaN`, `Infinity` or `-Infinity` (bare,
/// as Python writes them): they reach `T` as strings its fields read with
/// [`non_finite`]. Never for scenes, which must be finite.
pub fn from_slice_non_finite<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, Failure> {
    from_slice(&quote_non_finite(bytes))
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

    #[test]
    fn non_finite_words_become_strings_of_the_same_length_outside_strings_only() {
        let text = br#"[NaN, Infinity,-Infinity, "NaN x", "a\"NaN", NaNa, 1]"#;
        let q = quote_non_finite(text);
        assert_eq!(q.len(), text.len());
        assert_eq!(
            std::str::from_utf8(&q).unwrap(),
            r#"["N", "Infini","-Infini", "NaN x", "a\"NaN", NaNa, 1]"#
        );
        assert!(matches!(quote_non_finite(b"[1, 2]"), Cow::Borrowed(_)));
        assert!(non_finite("N").unwrap().is_nan());
        assert_eq!(non_finite("-Infinity"), Some(f64::NEG_INFINITY));
        assert_eq!(non_finite("nan"), None);
        // The strict reader, the scenes', still refuses them.
        assert!(from_slice::<Vec<f64>>(b"[NaN]").is_err());
        let v: Vec<String> = from_slice_non_finite(b"[NaN, Infinity]").unwrap();
        assert_eq!(v, vec!["N", "Infini"]);
        // An error after a stand-in is at the column of the bytes as sent.
        let f = from_slice_non_finite::<Vec<String>>(b"[NaN, x]").unwrap_err();
        assert_eq!((f.error.line(), f.error.column()), (1, 7));
    }
}
