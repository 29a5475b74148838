//! Reference values made by an independent tool (scipy / python-control / the C reference of
//! xoshiro256++) with `tools/fixtures/make_fixtures.py`; tests compare against them.

use nalgebra::DMatrix;
use serde_json::Value;
use std::sync::OnceLock;

pub fn reference() -> &'static Value {
    static REF: OnceLock<Value> = OnceLock::new();
    REF.get_or_init(|| {
        serde_json::from_str(include_str!("../fixtures/reference.json"))
            .expect("controller/fixtures/reference.json is valid JSON")
    })
}

/// A matrix from nested row-major lists (a flat list is a column).
pub fn matrix(v: &Value) -> DMatrix<f64> {
    let rows = v.as_array().expect("matrix is a list");
    if rows.first().is_some_and(|r| r.is_array()) {
        let cols = rows[0].as_array().unwrap().len();
        DMatrix::from_fn(rows.len(), cols, |i, j| rows[i][j].as_f64().unwrap())
    } else {
        DMatrix::from_fn(rows.len(), 1, |i, _| rows[i].as_f64().unwrap())
    }
}

/// Poles as [re, im] pairs.
pub fn poles(v: &Value) -> Vec<[f64; 2]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
        .collect()
}
