//! Finds the first non-finite number in anything serde can serialize, by its path
//! (`pass_ms[3].median`). `serde_json` writes NaN and infinities as `null`, which a reader
//! cannot tell from a missing value; [`super::write_json`] refuses such a report instead.

use serde::Serialize;
use serde::ser;
use std::fmt;

/// The path of the first NaN or infinity in `value` (`""` for a bare number), or `None`
/// when every number in it is finite.
pub fn first_non_finite<T: Serialize + ?Sized>(value: &T) -> Option<(String, f64)> {
    let mut c = Checker { path: Vec::new() };
    match value.serialize(&mut c) {
        Ok(()) => None,
        Err(Stop::Found(path, v)) => Some((path, v)),
        // A serializer error of the value's own (a map key that is no string): not ours to
        // report here; the JSON encoder reports it.
        Err(Stop::Other(_)) => None,
    }
}

#[derive(Debug)]
enum Stop {
    Found(String, f64),
    Other(String),
}

impl fmt::Display for Stop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Stop::Found(p, v) => write!(f, "{v} at {p}"),
            Stop::Other(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for Stop {}

impl ser::Error for Stop {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        Stop::Other(msg.to_string())
    }
}

enum Seg {
    Field(&'static str),
    Index(usize),
    Key(String),
}

struct Checker {
    path: Vec<Seg>,
}

impl Checker {
    fn path(&self) -> String {
        let mut s = String::new();
        for seg in &self.path {
            match seg {
                Seg::Field(f) => {
                    if !s.is_empty() {
                        s.push('.');
                    }
                    s.push_str(f);
                }
                Seg::Index(i) => s.push_str(&format!("[{i}]")),
                Seg::Key(k) => s.push_str(&format!("[{k}]")),
            }
        }
        s
    }

    fn number(&self, v: f64) -> Result<(), Stop> {
        if v.is_finite() {
            Ok(())
        } else {
            Err(Stop::Found(self.path(), v))
        }
    }

    fn nested<T: Serialize + ?Sized>(&mut self, seg: Seg, value: &T) -> Result<(), Stop> {
        self.path.push(seg);
        let r = value.serialize(&mut *self);
        self.path.pop();
        r
    }
}

/// Sequences, tuples, maps and structs: counts elements for their indices.
struct Compound<'a> {
    c: &'a mut Checker,
    index: usize,
    key: Option<String>,
}

impl<'a> Compound<'a> {
    fn new(c: &'a mut Checker) -> Self {
        Compound {
            c,
            index: 0,
            key: None,
        }
    }

    fn element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        let i = self.index;
        self.index += 1;
        self.c.nested(Seg::Index(i), value)
    }
}

macro_rules! ints {
    ($($f:ident: $t:ty),*) => {
        $(fn $f(self, _: $t) -> Result<(), Stop> { Ok(()) })*
    };
}

impl<'a> ser::Serializer for &'a mut Checker {
    type Ok = ();
    type Error = Stop;
    type SerializeSeq = Compound<'a>;
    type SerializeTuple = Compound<'a>;
    type SerializeTupleStruct = Compound<'a>;
    type SerializeTupleVariant = Compound<'a>;
    type SerializeMap = Compound<'a>;
    type SerializeStruct = Compound<'a>;
    type SerializeStructVariant = Compound<'a>;

    ints!(serialize_bool: bool, serialize_i8: i8, serialize_i16: i16, serialize_i32: i32,
        serialize_i64: i64, serialize_i128: i128, serialize_u8: u8, serialize_u16: u16,
        serialize_u32: u32, serialize_u64: u64, serialize_u128: u128, serialize_char: char,
        serialize_str: &str, serialize_bytes: &[u8]);

    fn serialize_f32(self, v: f32) -> Result<(), Stop> {
        self.number(v as f64)
    }
    fn serialize_f64(self, v: f64) -> Result<(), Stop> {
        self.number(v)
    }
    fn serialize_none(self) -> Result<(), Stop> {
        Ok(())
    }
    fn serialize_some<T: Serialize + ?Sized>(self, value: &T) -> Result<(), Stop> {
        value.serialize(self)
    }
    fn serialize_unit(self) -> Result<(), Stop> {
        Ok(())
    }
    fn serialize_unit_struct(self, _: &'static str) -> Result<(), Stop> {
        Ok(())
    }
    fn serialize_unit_variant(self, _: &'static str, _: u32, _: &'static str) -> Result<(), Stop> {
        Ok(())
    }
    fn serialize_newtype_struct<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        value: &T,
    ) -> Result<(), Stop> {
        value.serialize(self)
    }
    fn serialize_newtype_variant<T: Serialize + ?Sized>(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        value: &T,
    ) -> Result<(), Stop> {
        self.nested(Seg::Field(variant), value)
    }
    fn serialize_seq(self, _: Option<usize>) -> Result<Compound<'a>, Stop> {
        Ok(Compound::new(self))
    }
    fn serialize_tuple(self, _: usize) -> Result<Compound<'a>, Stop> {
        Ok(Compound::new(self))
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, Stop> {
        Ok(Compound::new(self))
    }
    fn serialize_tuple_variant(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, Stop> {
        self.path.push(Seg::Field(variant));
        Ok(Compound::new(self))
    }
    fn serialize_map(self, _: Option<usize>) -> Result<Compound<'a>, Stop> {
        Ok(Compound::new(self))
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> Result<Compound<'a>, Stop> {
        Ok(Compound::new(self))
    }
    fn serialize_struct_variant(
        self,
        _: &'static str,
        _: u32,
        variant: &'static str,
        _: usize,
    ) -> Result<Compound<'a>, Stop> {
        self.path.push(Seg::Field(variant));
        Ok(Compound::new(self))
    }
}

impl ser::SerializeSeq for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        self.element(value)
    }
    fn end(self) -> Result<(), Stop> {
        Ok(())
    }
}

impl ser::SerializeTuple for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_element<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        self.element(value)
    }
    fn end(self) -> Result<(), Stop> {
        Ok(())
    }
}

impl ser::SerializeTupleStruct for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_field<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        self.element(value)
    }
    fn end(self) -> Result<(), Stop> {
        Ok(())
    }
}

impl ser::SerializeTupleVariant for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_field<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        self.element(value)
    }
    fn end(self) -> Result<(), Stop> {
        self.c.path.pop();
        Ok(())
    }
}

impl ser::SerializeMap for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_key<T: Serialize + ?Sized>(&mut self, key: &T) -> Result<(), Stop> {
        // A float key is checked like any number; its text names the value that follows.
        key.serialize(&mut *self.c)?;
        self.key = Some(match serde_json::to_value(key) {
            Ok(serde_json::Value::String(s)) => s,
            Ok(v) => v.to_string(),
            Err(_) => format!("key {}", self.index),
        });
        Ok(())
    }
    fn serialize_value<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), Stop> {
        let key = self
            .key
            .take()
            .unwrap_or_else(|| format!("key {}", self.index));
        self.index += 1;
        self.c.nested(Seg::Key(key), value)
    }
    fn end(self) -> Result<(), Stop> {
        Ok(())
    }
}

impl ser::SerializeStruct for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_field<T: Serialize + ?Sized>(
        &mut self,
        name: &'static str,
        value: &T,
    ) -> Result<(), Stop> {
        self.c.nested(Seg::Field(name), value)
    }
    fn end(self) -> Result<(), Stop> {
        Ok(())
    }
}

impl ser::SerializeStructVariant for Compound<'_> {
    type Ok = ();
    type Error = Stop;
    fn serialize_field<T: Serialize + ?Sized>(
        &mut self,
        name: &'static str,
        value: &T,
    ) -> Result<(), Stop> {
        self.c.nested(Seg::Field(name), value)
    }
    fn end(self) -> Result<(), Stop> {
        self.c.path.pop();
        Ok(())
    }
}

/// `#[serde(serialize_with = "crate::io::finite::nan_as_null")]` on a report field whose
/// NaN means "not measured" (a GPU time on a queue without timestamps, the PSNR of an empty
/// pixel set): written as `null`, which [`first_non_finite`] accepts. Infinities and NaN
/// in any other field are still refused.
pub fn nan_as_null<S: ser::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_nan() {
        s.serialize_none()
    } else {
        s.serialize_f64(*v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[derive(Serialize)]
    struct Pass {
        name: &'static str,
        median: f64,
        samples: Vec<f32>,
    }

    #[derive(Serialize)]
    enum Shape {
        Point([f32; 3]),
        Box { lo: [f32; 3], hi: [f32; 3] },
    }

    #[derive(Serialize)]
    struct Report {
        passes: Vec<Pass>,
        shapes: Vec<Shape>,
        by_name: BTreeMap<String, (u32, f32)>,
        missing: Option<f64>,
    }

    fn report() -> Report {
        Report {
            passes: vec![
                Pass {
                    name: "a",
                    median: 1.0,
                    samples: vec![1.0, 2.0],
                },
                Pass {
                    name: "b",
                    median: 2.0,
                    samples: vec![3.0, 4.0],
                },
            ],
            shapes: vec![
                Shape::Point([0.0; 3]),
                Shape::Box {
                    lo: [0.0; 3],
                    hi: [1.0; 3],
                },
            ],
            by_name: BTreeMap::from([("x".to_string(), (1, 0.5)), ("y".to_string(), (2, 0.25))]),
            missing: None,
        }
    }

    #[test]
    fn finds_the_first_non_finite_number_by_its_path() {
        assert_eq!(first_non_finite(&report()), None);
        assert_eq!(first_non_finite(&1.5f32), None);
        assert_eq!(
            first_non_finite(&f64::NAN).map(|p| p.0),
            Some(String::new())
        );
        let mut r = report();
        r.passes[1].samples[1] = f32::INFINITY;
        assert_eq!(
            first_non_finite(&r),
            Some(("passes[1].samples[1]".into(), f64::INFINITY))
        );
        let mut r = report();
        r.passes[0].median = f64::NAN;
        r.missing = Some(f64::NEG_INFINITY);
        assert_eq!(first_non_finite(&r).unwrap().0, "passes[0].median");
        let mut r = report();
        r.missing = Some(f64::NEG_INFINITY);
        assert_eq!(
            first_non_finite(&r),
            Some(("missing".into(), f64::NEG_INFINITY))
        );
        let mut r = report();
        r.shapes[1] = Shape::Box {
            lo: [0.0; 3],
            hi: [1.0, f32::NAN, 1.0],
        };
        assert_eq!(first_non_finite(&r).unwrap().0, "shapes[1].Box.hi[1]");
        let mut r = report();
        r.shapes[0] = Shape::Point([0.0, 0.0, f32::NAN]);
        assert_eq!(first_non_finite(&r).unwrap().0, "shapes[0].Point[2]");
        let mut r = report();
        r.by_name.get_mut("y").unwrap().1 = f32::NAN;
        assert_eq!(first_non_finite(&r).unwrap().0, "by_name[y][1]");
    }

    #[test]
    fn a_nan_marked_not_measured_is_null_and_accepted() {
        #[derive(Serialize)]
        struct Timing {
            #[serde(serialize_with = "super::nan_as_null")]
            gpu_ms: f64,
            fps: f64,
        }
        let t = Timing {
            gpu_ms: f64::NAN,
            fps: 30.0,
        };
        assert_eq!(first_non_finite(&t), None);
        assert_eq!(
            serde_json::to_string(&t).unwrap(),
            r#"{"gpu_ms":null,"fps":30.0}"#
        );
        let t = Timing {
            gpu_ms: f64::INFINITY,
            fps: f64::NAN,
        };
        assert_eq!(first_non_finite(&t).unwrap().0, "gpu_ms");
    }
}
