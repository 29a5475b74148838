//! bdft-lab's wire types: every message that crosses a process boundary, the parameters
//! they carry, and their one encoding. Internals (nalgebra states, database rows) convert
//! to these at the boundary.

pub mod params;
