//! Validation of responses against the served OpenAPI document, strict
//! (members the schema does not name are refused): `tests/it/contract.rs`
//! checks a station's routes with it, `tests/it/fleet.rs` the fleet role's.
#![allow(dead_code)]

use serde_json::{json, Map, Value};
use std::collections::{BTreeMap, BTreeSet};

/// An object shape: its properties and its required member names.
pub type Shape = (Map<String, Value>, Vec<Value>);

/// Every shape of `a` merged with every shape of `b` (properties and
/// required names of both).
pub fn product(a: &[Shape], b: &[Shape]) -> Vec<Shape> {
    let mut out = vec![];
    for (p, r) in a {
        for (bp, br) in b {
            let mut p = p.clone();
            p.extend(bp.iter().map(|(k, x)| (k.clone(), x.clone())));
            let mut r = r.clone();
            r.extend(br.iter().cloned());
            out.push((p, r));
        }
    }
    out
}

/// Turns a schema into one that refuses unnamed members: every object
/// schema with `properties` gets `additionalProperties: false`; an `allOf`
/// of object schemas (serde `flatten`) is merged into one object first.
pub struct Strict<'a> {
    schemas: &'a Map<String, Value>,
}

impl Strict<'_> {
    fn resolve<'b>(&'b self, v: &'b Value) -> &'b Value {
        match v.get("$ref").and_then(Value::as_str) {
            Some(r) => {
                let name = r
                    .strip_prefix("#/components/schemas/")
                    .expect("a component reference");
                self.schemas
                    .get(name)
                    .unwrap_or_else(|| panic!("no schema {name}"))
            }
            None => v,
        }
    }

    /// The object shapes a schema allows, each as (properties, required);
    /// None when it is not made of plain object schemas. An `allOf` is the
    /// product of its members' shapes, a `oneOf` / `anyOf` their union (a
    /// serde-flattened tagged enum).
    fn shapes(&self, v: &Value) -> Option<Vec<Shape>> {
        let v = self.resolve(v);
        if v.get("additionalProperties").is_some() {
            return None;
        }
        let mut own = (Map::new(), vec![]);
        if let Some(p) = v.get("properties").and_then(Value::as_object) {
            own.0 = p.clone();
        }
        if let Some(r) = v.get("required").and_then(Value::as_array) {
            own.1 = r.clone();
        }
        let mut out = vec![own];
        if let Some(all) = v.get("allOf").and_then(Value::as_array) {
            for m in all {
                out = product(&out, &self.shapes(m)?);
            }
        }
        if let Some(one) = v
            .get("oneOf")
            .or_else(|| v.get("anyOf"))
            .and_then(Value::as_array)
        {
            let mut alts = vec![];
            for m in one {
                alts.extend(self.shapes(m)?);
            }
            out = product(&out, &alts);
        }
        Some(out)
    }

    fn apply(&self, v: &Value) -> Value {
        match v {
            Value::Object(o) => {
                if o.get("allOf").is_some() {
                    if let Some(shapes) = self.shapes(v) {
                        let objects: Vec<Value> = shapes
                            .into_iter()
                            .map(|(props, req)| {
                                let props: Map<String, Value> = props
                                    .iter()
                                    .map(|(k, s)| (k.clone(), self.apply(s)))
                                    .collect();
                                json!({"type": "object", "properties": props, "required": req,
                                       "additionalProperties": false})
                            })
                            .collect();
                        return if objects.len() == 1 {
                            objects.into_iter().next().unwrap()
                        } else {
                            json!({"anyOf": objects})
                        };
                    }
                }
                let mut out: Map<String, Value> =
                    o.iter().map(|(k, x)| (k.clone(), self.apply(x))).collect();
                if o.get("properties").is_some() && o.get("additionalProperties").is_none() {
                    out.insert("additionalProperties".into(), json!(false));
                }
                Value::Object(out)
            }
            Value::Array(a) => Value::Array(a.iter().map(|x| self.apply(x)).collect()),
            x => x.clone(),
        }
    }
}

/// Validates responses against the served document and records which
/// (method, path) pairs and statuses were seen.
pub struct Contract {
    pub doc: Value,
    strict_schemas: Value,
    /// The (status codes) each (method, route template) answered with a validated response.
    pub seen: BTreeMap<(String, String), BTreeSet<u16>>,
}

impl Contract {
    pub fn new(doc: Value) -> Contract {
        let schemas = doc["components"]["schemas"]
            .as_object()
            .expect("components.schemas")
            .clone();
        let strict = Strict { schemas: &schemas };
        let strict_schemas: Map<String, Value> = schemas
            .iter()
            .map(|(k, v)| (k.clone(), strict.apply(v)))
            .collect();
        Contract {
            doc,
            strict_schemas: Value::Object(strict_schemas),
            seen: BTreeMap::new(),
        }
    }

    /// Checks one response; returns the body as JSON (Null for other types).
    pub fn check(
        &mut self,
        method: &str,
        path: &str,
        status: u16,
        content_type: &str,
        body: &[u8],
    ) -> Value {
        let op = &self.doc["paths"][path][method];
        assert!(op.is_object(), "{method} {path}: not in the document");
        let responses = &op["responses"];
        let resp = if responses[status.to_string()].is_object() {
            &responses[status.to_string()]
        } else if status >= 400 && responses["default"].is_object() {
            &responses["default"]
        } else {
            panic!(
                "{method} {path}: status {status} is not documented: {}",
                String::from_utf8_lossy(body)
            )
        };
        let what = format!("{method} {path} {status}");
        let ct = content_type
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_string();
        let content = &resp["content"];
        let mut out = Value::Null;
        if status == 101 || status == 204 {
            assert!(body.is_empty(), "{what}: a body");
            assert!(content.is_null(), "{what}: documents a body");
        } else {
            let media = &content[&ct];
            assert!(
                media.is_object(),
                "{what}: content type {ct:?} not documented ({:?})",
                content.as_object().map(|o| o.keys().collect::<Vec<_>>())
            );
            if ct == "application/json" || ct == "application/problem+json" {
                let v: Value = serde_json::from_slice(body)
                    .unwrap_or_else(|e| panic!("{what}: not JSON: {e}"));
                self.validate(&what, &media["schema"], &v);
                out = v;
            } else {
                assert!(!body.is_empty(), "{what}: empty body");
                match ct.as_str() {
                    "audio/wav" => assert_eq!(&body[..4], b"RIFF", "{what}"),
                    "image/svg+xml" => {
                        assert!(String::from_utf8_lossy(body).contains("<svg"), "{what}")
                    }
                    _ => {
                        assert!(std::str::from_utf8(body).is_ok(), "{what}: not text")
                    }
                }
            }
        }
        self.seen
            .entry((method.to_string(), path.to_string()))
            .or_default()
            .insert(status);
        out
    }

    /// Reads `resp` and checks it as [`Contract::check`] does; its status and
    /// its body as JSON.
    pub async fn take(
        &mut self,
        method: &str,
        path: &str,
        resp: reqwest::Response,
    ) -> (u16, Value) {
        let status = resp.status().as_u16();
        let ct = resp
            .headers()
            .get("content-type")
            .map(|v| v.to_str().unwrap().to_string())
            .unwrap_or_default();
        let bytes = resp.bytes().await.unwrap();
        let v = self.check(method, path, status, &ct, &bytes);
        (status, v)
    }

    pub fn validate(&self, what: &str, schema: &Value, v: &Value) {
        let errors = self.errors(what, schema, v);
        assert!(
            errors.is_empty(),
            "{what}: the response does not match its schema:\n  {}\nschema: {schema}\nbody: {}",
            errors.join("\n  "),
            short(v)
        );
    }

    pub fn errors(&self, what: &str, schema: &Value, v: &Value) -> Vec<String> {
        let strict = Strict {
            schemas: self.doc["components"]["schemas"].as_object().unwrap(),
        };
        let root = json!({
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "components": {"schemas": self.strict_schemas},
            "allOf": [strict.apply(schema)],
        });
        let validator = jsonschema::draft202012::new(&root)
            .unwrap_or_else(|e| panic!("{what}: the schema does not compile: {e}"));
        validator
            .iter_errors(v)
            .map(|e| format!("at {}: {e}", e.instance_path()))
            .take(8)
            .collect()
    }
}

pub fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.len() > 3000 {
        format!("{}...", &s[..3000])
    } else {
        s
    }
}
