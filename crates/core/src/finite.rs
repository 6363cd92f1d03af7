//! The last check before a result document is stored: every number finite.
//!
//! serde_json writes a NaN or an infinity as `null`, so a non-finite value in
//! a result would be stored silently as a missing one (issue 11). Documents
//! that go into the store are turned into JSON by [`to_value`], which walks the
//! value first and refuses it with the path of the first non-finite number
//! (e.g. `stiffness.k_n_per_m[3]`). Pure: no I/O.

use serde::ser::{self, Serialize};
use serde_json::Value;
use std::fmt;

/// A document refused because a number in it is NaN or infinite.
#[derive(Debug, Clone, PartialEq)]
pub struct NonFinite {
    /// Where: field names and `[index]`es from the document's root.
    pub path: String,
    pub value: f64,
    /// Any other serialisation error (not a non-finite number).
    other: Option<String>,
}

impl fmt::Display for NonFinite {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.other {
            Some(m) => write!(f, "{m}"),
            None => write!(
                f,
                "non-finite value {} at {} (not stored)",
                self.value,
                if self.path.is_empty() {
                    "the root"
                } else {
                    &self.path
                }
            ),
        }
    }
}

impl std::error::Error for NonFinite {}

impl ser::Error for NonFinite {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        NonFinite {
            path: String::new(),
            value: f64::NAN,
            other: Some(msg.to_string()),
        }
    }
}

/// `serde_json::to_value`, refusing any NaN or infinity in `v`.
pub fn to_value<T: Serialize + ?Sized>(v: &T) -> Result<Value, NonFinite> {
    check(v)?;
    serde_json::to_value(v).map_err(<NonFinite as ser::Error>::custom)
}

/// `Ok` if every floating-point number in `v` is finite.
pub fn check<T: Serialize + ?Sized>(v: &T) -> Result<(), NonFinite> {
    v.serialize(&mut Walk { path: vec![] })
}

/// Also for documents that are JSON already (numbers there are finite by
/// construction; kept for symmetry of the store's checks).
struct Walk {
    path: Vec<String>,
}

impl Walk {
    fn float(&self, v: f64) -> Result<(), NonFinite> {
        if v.is_finite() {
            Ok(())
        } else {
            let mut p = String::new();
            for s in &self.path {
                if !s.starts_with('[') && !p.is_empty() {
                    p.push('.');
                }
                p.push_str(s);
            }
            Err(NonFinite {
                path: p,
                value: v,
                other: None,
            })
        }
    }
    fn nested<T: Serialize + ?Sized>(&mut self, key: String, v: &T) -> Result<(), NonFinite> {
        self.path.push(key);
        let r = v.serialize(&mut *self);
        self.path.pop();
        r
    }
}

fn key_name<T: Serialize + ?Sized>(k: &T) -> String {
    match serde_json::to_value(k) {
        Ok(Value::String(s)) => s,
        Ok(v) => v.to_string(),
        Err(_) => "?".into(),
    }
}

/// Compound values: sequences count their items, structs and maps name them.
struct Compound<'a> {
    w: &'a mut Walk,
    i: usize,
    key: Option<String>,
}

impl Compound<'_> {
    fn item<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), NonFinite> {
        let k = format!("[{}]", self.i);
        self.i += 1;
        self.w.nested(k, v)
    }
}

macro_rules! seq_like {
    ($($tr:ident :: $m:ident),*) => {$(
        impl ser::$tr for Compound<'_> {
            type Ok = ();
            type Error = NonFinite;
            fn $m<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), NonFinite> {
                self.item(v)
            }
            fn end(self) -> Result<(), NonFinite> {
                Ok(())
            }
        }
    )*};
}
seq_like!(
    SerializeSeq::serialize_element,
    SerializeTuple::serialize_element,
    SerializeTupleStruct::serialize_field,
    SerializeTupleVariant::serialize_field
);

macro_rules! struct_like {
    ($($tr:ident),*) => {$(
        impl ser::$tr for Compound<'_> {
            type Ok = ();
            type Error = NonFinite;
            fn serialize_field<T: Serialize + ?Sized>(
                &mut self,
                key: &'static str,
                v: &T,
            ) -> Result<(), NonFinite> {
                self.w.nested(key.to_string(), v)
            }
            fn end(self) -> Result<(), NonFinite> {
                Ok(())
            }
        }
    )*};
}
struct_like!(SerializeStruct, SerializeStructVariant);

impl ser::SerializeMap for Compound<'_> {
    type Ok = ();
    type Error = NonFinite;
    fn serialize_key<T: Serialize + ?Sized>(&mut self, k: &T) -> Result<(), NonFinite> {
        k.serialize(&mut *self.w)?;
        self.key = Some(key_name(k));
        Ok(())
    }
    fn serialize_value<T: Serialize + ?Sized>(&mut self, v: &T) -> Result<(), NonFinite> {
        let k = self.key.take().unwrap_or_default();
        self.w.nested(k, v)
    }
    fn end(self) -> Result<(), NonFinite> {
        Ok(())
    }
}

impl<'a> ser::Serializer for &'a mut Walk {
    type Ok = ();
    type Error = NonFinite;
    type SerializeSeq = Compound<'a>;
    type SerializeTuple = Compound<'a>;
    type SerializeTupleStruct = Compound<'a>;
    type SerializeTupleVariant = Compound<'a>;
    type SerializeMap = Compound<'a>;
    type SerializeStruct = Compound<'a>;
    type SerializeStructVariant = Compound<'a>;

    fn serialize_f32(self, v: f32) -> Result<(), NonFinite> {
        self.float(v as f64)
    }
    fn serialize_f64(self, v: f64) -> Result<(), NonFinite> {
        self.float(v)
    }
    fn serialize_bool(self, _: bool) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_i8(self, _: i8) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_i16(self, _: i16) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_i32(self, _: i32) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_i64(self, _: i64) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_u8(self, _: u8) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_u16(self, _: u16) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_u32(self, _: u32) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_u64(self, _: u64) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_char(self, _: char) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_str(self, _: &str) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_bytes(self, _: &[u8]) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_none(self) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_some<T: Serialize + ?Sized>(self, v: &T) -> Result<(), NonFinite> {
        v.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_unit_struct(self, _: &'static str) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_unit_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
    ) -> Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_newtype_struct<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        v: &T,
    ) -> Result<(), NonFinite> {
        v.serialize(self)
    }
    fn serialize_newtype_variant<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        v: &T,
    ) -> Result<(), NonFinite> {
        self.nested(variant.to_string(), v)
    }
    fn serialize_seq(self, _: Option<usize>) -> Result<Compound<'a>, NonFinite> {
        Ok(Compound {
            w: self,
            i: 0,
            key: None,
        })
    }
    fn serialize_tuple(self, _: usize) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
    fn serialize_tuple_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
    fn serialize_map(self, _: Option<usize>) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
    fn serialize_struct_variant(
        self,
        _: &'static str,
        _: u32,
        _: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, NonFinite> {
        self.serialize_seq(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Serialize;
    use std::collections::BTreeMap;

    #[derive(Serialize)]
    struct Stiffness {
        k_n_per_m: Vec<f64>,
        x_m: Option<f64>,
    }

    #[derive(Serialize)]
    struct Doc {
        f0_hz: f64,
        stiffness: Stiffness,
        by_name: BTreeMap<String, f32>,
        levels: Vec<(u32, f64)>,
    }

    fn doc() -> Doc {
        Doc {
            f0_hz: 38.5,
            stiffness: Stiffness {
                k_n_per_m: vec![1200.0, -3.0e4, 2.0e7],
                x_m: None,
            },
            by_name: [("a".to_string(), 1.5f32)].into(),
            levels: vec![(1, 0.002), (2, 0.004)],
        }
    }

    #[test]
    fn finite_documents_are_the_json_serde_writes() {
        let d = doc();
        assert_eq!(to_value(&d).unwrap(), serde_json::to_value(&d).unwrap());
    }

    #[test]
    fn a_nan_or_infinity_anywhere_is_refused_with_its_path() {
        let mut d = doc();
        d.stiffness.k_n_per_m[2] = f64::NAN;
        let e = to_value(&d).unwrap_err();
        assert_eq!(e.path, "stiffness.k_n_per_m[2]");
        assert!(e.value.is_nan());
        // serde_json alone would have stored a null there.
        assert_eq!(
            serde_json::to_value(&d).unwrap()["stiffness"]["k_n_per_m"][2],
            Value::Null
        );

        let mut d = doc();
        d.stiffness.x_m = Some(f64::INFINITY);
        assert_eq!(to_value(&d).unwrap_err().path, "stiffness.x_m");
        let mut d = doc();
        d.by_name.insert("b".into(), f32::NEG_INFINITY);
        assert_eq!(to_value(&d).unwrap_err().path, "by_name.b");
        let mut d = doc();
        d.levels[1].1 = f64::NAN;
        let e = to_value(&d).unwrap_err();
        assert_eq!(e.path, "levels[1][1]");
        assert!(e.to_string().contains("levels[1][1]"), "{e}");
        assert_eq!(to_value(&f64::NAN).unwrap_err().path, "");
    }
}
