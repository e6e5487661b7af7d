//! A fitness value that serialises +inf (a failed evaluation, or "nothing yet") losslessly.
//!
//! JSON has no infinity, and serde_json would write `null` and then refuse to read it
//! back. Finite values serialise as plain numbers (bit-exact with serde_json's
//! `float_roundtrip`), +inf as the string `"inf"`.

use serde::de::{self, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
pub(crate) struct Fit(pub(crate) f64);

impl Serialize for Fit {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if self.0 == f64::INFINITY {
            s.serialize_str("inf")
        } else {
            s.serialize_f64(self.0)
        }
    }
}

impl<'de> Deserialize<'de> for Fit {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl Visitor<'_> for V {
            type Value = Fit;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or \"inf\"")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Fit, E> {
                Ok(Fit(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Fit, E> {
                Ok(Fit(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Fit, E> {
                Ok(Fit(v as f64))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Fit, E> {
                if v == "inf" {
                    Ok(Fit(f64::INFINITY))
                } else {
                    Err(E::invalid_value(de::Unexpected::Str(v), &self))
                }
            }
        }
        d.deserialize_any(V)
    }
}
