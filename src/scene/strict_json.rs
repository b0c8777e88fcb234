//! JSON text to a [`Value`] that notes every duplicated key.
//!
//! serde_json keeps the last of two equal keys in an object and says nothing, so a
//! document could mean two things. This reader builds the same `Value` (the last one
//! still wins, so the other checks see what they always saw) and lists each repeated
//! member with its JSON pointer, to be reported with the document's other problems.

use std::fmt;

use serde::Deserializer;
use serde::de::{DeserializeSeed, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

use super::Scene;
use super::problem::{Pointer, Problem, SceneError};

/// At most this many problems are listed in all, the rest counted, as validation does.
const MAX_PROBLEMS: usize = 100;

/// How validation words the count of problems it left out.
const NOT_LISTED: &str = " more problems not listed";

/// The duplicated members of a document, in document order.
#[derive(Debug, Default)]
pub(crate) struct Duplicates {
    list: Vec<Problem>,
    dropped: usize,
}

impl Duplicates {
    /// The duplicated members as problems, with a note counting those not listed.
    pub(crate) fn into_problems(self) -> Vec<Problem> {
        let mut list = self.list;
        if self.dropped > 0 {
            list.push(Problem::new("", format!("{}{NOT_LISTED}", self.dropped)));
        }
        list
    }

    fn add(&mut self, at: Option<&Link<'_>>, key: &str) {
        if self.list.len() < MAX_PROBLEMS {
            self.list.push(Problem::new(
                pointer(at).key(key).to_string(),
                format!("duplicate key `{key}`"),
            ));
        } else {
            self.dropped += 1;
        }
    }
}

/// Reads one JSON value from `d`. A value serde_json would not read fails the same way,
/// with the path of the failing value (as `serde_path_to_error` gives it).
pub(crate) fn deserialize<'de, D: Deserializer<'de>>(
    d: D,
) -> Result<(Value, Duplicates), serde_path_to_error::Error<D::Error>> {
    let mut track = serde_path_to_error::Track::new();
    let mut duplicates = Duplicates::default();
    let seed = ValueSeed {
        duplicates: &mut duplicates,
        at: None,
    };
    match seed.deserialize(serde_path_to_error::Deserializer::new(d, &mut track)) {
        Ok(v) => Ok((v, duplicates)),
        Err(e) => Err(serde_path_to_error::Error::new(track.path(), e)),
    }
}

/// The outcome of validating a document, with its duplicated members listed first.
pub(crate) fn with_duplicates(
    duplicates: Duplicates,
    outcome: Result<Scene, SceneError>,
) -> Result<Scene, SceneError> {
    if duplicates.list.is_empty() {
        return outcome;
    }
    let mut others = match outcome {
        Ok(_) => Vec::new(),
        Err(SceneError::Invalid(p)) => p,
        Err(e) => return Err(e),
    };
    let mut dropped = duplicates.dropped;
    if let Some(n) = others.last().and_then(not_listed) {
        dropped += n;
        others.pop();
    }
    let mut all = duplicates.list;
    all.append(&mut others);
    if all.len() > MAX_PROBLEMS {
        dropped += all.len() - MAX_PROBLEMS;
        all.truncate(MAX_PROBLEMS);
    }
    if dropped > 0 {
        all.push(Problem::new("", format!("{dropped}{NOT_LISTED}")));
    }
    Err(SceneError::Invalid(all))
}

/// How many problems `p` says were left out, if it is that note.
fn not_listed(p: &Problem) -> Option<usize> {
    if !p.pointer.is_empty() {
        return None;
    }
    p.message.strip_suffix(NOT_LISTED)?.parse().ok()
}

/// Where a value is, as a chain up to the root: built on the stack while reading, and
/// turned into a pointer only for a duplicate.
enum Segment<'a> {
    Key(&'a str),
    Index(usize),
}

struct Link<'a> {
    segment: Segment<'a>,
    parent: Option<&'a Link<'a>>,
}

fn pointer(at: Option<&Link<'_>>) -> Pointer<'static> {
    let mut segments = Vec::new();
    let mut next = at;
    while let Some(link) = next {
        segments.push(&link.segment);
        next = link.parent;
    }
    segments
        .into_iter()
        .rev()
        .fold(Pointer::root(), |p, s| match s {
            Segment::Key(k) => p.key(k).owned(),
            Segment::Index(i) => p.index(*i).owned(),
        })
}

/// Builds a value as serde_json's own `Value` does, noting duplicates on the way.
struct ValueSeed<'a> {
    duplicates: &'a mut Duplicates,
    at: Option<&'a Link<'a>>,
}

impl<'de> DeserializeSeed<'de> for ValueSeed<'_> {
    type Value = Value;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for ValueSeed<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any valid JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_f64<E>(self, v: f64) -> Result<Value, E> {
        Ok(Number::from_f64(v).map_or(Value::Null, Value::Number))
    }

    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }

    fn visit_none<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        self.deserialize(d)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut items = Vec::new();
        loop {
            let link = Link {
                segment: Segment::Index(items.len()),
                parent: self.at,
            };
            let seed = ValueSeed {
                duplicates: &mut *self.duplicates,
                at: Some(&link),
            };
            match seq.next_element_seed(seed)? {
                Some(v) => items.push(v),
                None => return Ok(Value::Array(items)),
            }
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut members = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let link = Link {
                segment: Segment::Key(&key),
                parent: self.at,
            };
            let value = map.next_value_seed(ValueSeed {
                duplicates: &mut *self.duplicates,
                at: Some(&link),
            })?;
            if members.contains_key(&key) {
                self.duplicates.add(self.at, &key);
            }
            members.insert(key, value);
        }
        Ok(Value::Object(members))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> (Value, Vec<Problem>) {
        let mut de = serde_json::Deserializer::from_str(text);
        let (v, d) = deserialize(&mut de).unwrap();
        de.end().unwrap();
        (v, d.list)
    }

    #[test]
    fn builds_the_value_serde_json_builds() {
        for text in [
            "null",
            "true",
            "-3",
            "18446744073709551615",
            "5.0",
            "1e-300",
            r#""a\u00e9""#,
            r#"[1, [2, {"a": []}], {}]"#,
            r#"{"b": 1, "a": {"c": [null, 2.5]}}"#,
            r#"{"a": 1, "a": 2}"#,
        ] {
            let expected: Value = serde_json::from_str(text).unwrap();
            assert_eq!(read(text).0, expected, "{text}");
        }
    }

    #[test]
    fn every_duplicate_is_listed_with_its_pointer() {
        let (v, d) = read(r#"{"a": [{"x": 1, "x": 2}], "b~/": {"y": 0, "y": 1, "y": 3}, "a": []}"#);
        assert_eq!(v, serde_json::json!({"a": [], "b~/": {"y": 3}}));
        let at: Vec<&str> = d.iter().map(|p| p.pointer.as_str()).collect();
        assert_eq!(at, ["/a/0/x", "/b~0~1/y", "/b~0~1/y", "/a"]);
        assert_eq!(d[0].message, "duplicate key `x`");
    }

    #[test]
    fn errors_carry_the_path_of_the_failing_value() {
        let mut de = serde_json::Deserializer::from_str(r#"{"a": [0, {"b": 1e999}]}"#);
        let e = deserialize(&mut de).unwrap_err();
        assert_eq!(e.path().to_string(), "a[1].b");
        assert!(e.inner().to_string().starts_with("number out of range"));
    }

    fn invalid(n: usize, at: &str) -> Vec<Problem> {
        (0..n).map(|_| Problem::new(at, "bad")).collect()
    }

    #[test]
    fn duplicates_come_first_and_the_count_of_the_rest_is_kept() {
        let dups = |n: usize| Duplicates {
            list: invalid(n.min(MAX_PROBLEMS), "/d"),
            dropped: n.saturating_sub(MAX_PROBLEMS),
        };
        let outcome = |n: usize, more: usize| {
            let mut p = invalid(n, "/o");
            if more > 0 {
                p.push(Problem::new("", format!("{more}{NOT_LISTED}")));
            }
            Err(SceneError::Invalid(p))
        };
        let problems = |r: Result<Scene, SceneError>| r.unwrap_err().problems().to_vec();

        let p = problems(with_duplicates(dups(2), outcome(3, 0)));
        let at: Vec<&str> = p.iter().map(|p| p.pointer.as_str()).collect();
        assert_eq!(at, ["/d", "/d", "/o", "/o", "/o"]);

        let p = problems(with_duplicates(dups(30), outcome(100, 20)));
        assert_eq!(p.len(), MAX_PROBLEMS + 1);
        assert_eq!(p[..30], invalid(30, "/d")[..]);
        assert_eq!(p[MAX_PROBLEMS].message, "50 more problems not listed");

        let p = problems(with_duplicates(dups(120), outcome(1, 0)));
        assert_eq!(p.len(), MAX_PROBLEMS + 1);
        assert_eq!(p[MAX_PROBLEMS].message, "21 more problems not listed");

        let syntax = SceneError::Syntax {
            message: "x".into(),
            line: 1,
            column: 1,
        };
        assert_eq!(
            with_duplicates(dups(1), Err(syntax.clone())).unwrap_err(),
            syntax
        );
    }
}
