//! Serde for a setting that can be switched off: `None` is written `false` (TOML has no `null`),
//! and read from `false` or `null`; `true` is refused (it names no value).
//!
//! Use on an `Option<T>` field: `#[serde(with = "crate::off")] #[schemars(with = "Option<T>")]`.

use std::fmt;
use std::marker::PhantomData;

use serde::de::value::{MapAccessDeserializer, SeqAccessDeserializer};
use serde::de::{self, IntoDeserializer, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Writes `None` as `false`, `Some(v)` as `v`.
///
/// # Errors
/// The serializer's.
pub fn serialize<T: Serialize, S: Serializer>(value: &Option<T>, s: S) -> Result<S::Ok, S::Error> {
    match value {
        None => s.serialize_bool(false),
        Some(v) => v.serialize(s),
    }
}

/// Reads `false` or `null` as `None`, anything else as a `T`.
///
/// # Errors
/// `true`, or what `T` refuses.
pub fn deserialize<'de, T: Deserialize<'de>, D: Deserializer<'de>>(d: D) -> Result<Option<T>, D::Error> {
    d.deserialize_any(OffOr(PhantomData))
}

struct OffOr<T>(PhantomData<T>);

impl<'de, T: Deserialize<'de>> Visitor<'de> for OffOr<T> {
    type Value = Option<T>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a value, or false to switch it off")
    }
    fn visit_bool<E: de::Error>(self, v: bool) -> Result<Self::Value, E> {
        if v { Err(E::custom("true names no value: give a value, or false to switch it off")) } else { Ok(None) }
    }
    fn visit_unit<E: de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }
    fn visit_none<E: de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }
    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        deserialize(d)
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
        T::deserialize(v.into_deserializer()).map(Some)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
        T::deserialize(v.into_deserializer()).map(Some)
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
        T::deserialize(v.into_deserializer()).map(Some)
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
        T::deserialize(v.into_deserializer()).map(Some)
    }
    fn visit_seq<A: de::SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
        T::deserialize(SeqAccessDeserializer::new(seq)).map(Some)
    }
    fn visit_map<A: de::MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
        T::deserialize(MapAccessDeserializer::new(map)).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct S {
        #[serde(with = "super")]
        x: Option<f64>,
        #[serde(with = "super")]
        p: Option<[f64; 3]>,
        #[serde(with = "super")]
        t: Option<T>,
    }
    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct T {
        r: f64,
    }

    #[test]
    fn off_is_false_both_ways_and_null_reads_as_off() {
        let on = S { x: Some(0.5), p: Some([1.0, -2.0, 3.0]), t: Some(T { r: 2.0 }) };
        let v = serde_json::to_value(&on).expect("write");
        assert_eq!(v, json!({"x": 0.5, "p": [1.0, -2.0, 3.0], "t": {"r": 2.0}}));
        assert_eq!(serde_json::from_value::<S>(v).expect("read"), on);
        let off = S { x: None, p: None, t: None };
        let v = serde_json::to_value(&off).expect("write");
        assert_eq!(v, json!({"x": false, "p": false, "t": false}));
        assert_eq!(serde_json::from_value::<S>(v).expect("read"), off);
        assert_eq!(serde_json::from_value::<S>(json!({"x": null, "p": null, "t": null})).expect("null"), off);
        let text = toml::to_string(&on).expect("toml");
        assert_eq!(toml::from_str::<S>(&text).expect("toml back"), on);
        assert_eq!(toml::from_str::<S>("x = false\np = false\nt = false").expect("toml off"), off);
        let e = serde_json::from_value::<S>(json!({"x": true, "p": false, "t": false})).expect_err("true");
        assert!(e.to_string().contains("false to switch it off"), "{e}");
        let e = serde_json::from_value::<S>(json!({"x": 1, "p": false, "t": {"q": 1}})).expect_err("unknown");
        assert!(e.to_string().contains('q'), "{e}");
    }
}
