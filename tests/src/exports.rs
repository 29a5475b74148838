//! Exports read back and compared as an analyst would read them: CSV as rows of cells,
//! Parquet as typed columns, and a comparison that is strict (equal bytes, or for Parquet the
//! same columns, types and values) and says exactly what differs when it fails.

use std::collections::BTreeSet;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float64Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

/// Quoted-field aware CSV parsing (the exports quote cells with commas, quotes, newlines).
pub fn parse_csv(text: &str) -> Vec<Vec<String>> {
    let (mut rows, mut row, mut cell) = (Vec::new(), Vec::new(), String::new());
    let (mut quoted, mut chars) = (false, text.chars().peekable());
    while let Some(c) = chars.next() {
        match (quoted, c) {
            (true, '"') if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            (true, '"') => quoted = false,
            (true, c) => cell.push(c),
            (false, '"') => quoted = true,
            (false, ',') => row.push(std::mem::take(&mut cell)),
            (false, '\n') => {
                row.push(std::mem::take(&mut cell));
                rows.push(std::mem::take(&mut row));
            }
            (false, c) => cell.push(c),
        }
    }
    rows
}

/// An export's format, from its file name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Csv,
    Parquet,
}

impl Format {
    pub fn of(file: &str) -> Self {
        if file.ends_with(".parquet") {
            Self::Parquet
        } else {
            Self::Csv
        }
    }
}

/// An export as a table: column names, their types (`text` for CSV) and cells (`None` is a
/// Parquet null).
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub columns: Vec<String>,
    pub types: Vec<String>,
    pub rows: Vec<Vec<Option<String>>>,
}

impl Table {
    pub fn read(bytes: &[u8], format: Format) -> Result<Self, String> {
        match format {
            Format::Csv => {
                let text = std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8: {e}"))?;
                let mut rows = parse_csv(text).into_iter();
                let columns = rows.next().unwrap_or_default();
                Ok(Self {
                    types: vec!["text".into(); columns.len()],
                    columns,
                    rows: rows.map(|r| r.into_iter().map(Some).collect()).collect(),
                })
            }
            Format::Parquet => parquet_table(bytes),
        }
    }
}

fn parquet_table(bytes: &[u8]) -> Result<Table, String> {
    let builder = ParquetRecordBatchReaderBuilder::try_new(bytes::Bytes::from(bytes.to_vec()))
        .map_err(|e| format!("not Parquet: {e}"))?;
    let schema = builder.schema().clone();
    let reader = builder.build().map_err(|e| format!("not Parquet: {e}"))?;
    let batches: Vec<RecordBatch> = reader
        .collect::<Result<_, _>>()
        .map_err(|e| format!("unreadable Parquet: {e}"))?;
    let mut rows = Vec::new();
    for b in &batches {
        for i in 0..b.num_rows() {
            rows.push(b.columns().iter().map(|a| cell(a.as_ref(), i)).collect());
        }
    }
    Ok(Table {
        columns: schema.fields().iter().map(|f| f.name().clone()).collect(),
        types: schema
            .fields()
            .iter()
            .map(|f| {
                format!(
                    "{}{}",
                    f.data_type(),
                    if f.is_nullable() { "?" } else { "" }
                )
            })
            .collect(),
        rows,
    })
}

/// A Parquet cell as exact text (a double's shortest round-trip form, so equal text is equal
/// bits).
fn cell(a: &dyn Array, i: usize) -> Option<String> {
    if a.is_null(i) {
        return None;
    }
    Some(match a.data_type() {
        DataType::Int64 => a.as_primitive::<Int64Type>().value(i).to_string(),
        DataType::Float64 => format!("{:?}", a.as_primitive::<Float64Type>().value(i)),
        DataType::Utf8 => a.as_string::<i32>().value(i).to_string(),
        DataType::Boolean => a.as_boolean().value(i).to_string(),
        t => format!("<{t}>"),
    })
}

/// How many differing cells a report lists.
const CELLS_LISTED: usize = 12;

/// Compares the export `file` made now with the one stored: equal bytes pass. Otherwise both
/// are read as tables and the report says what differs — columns removed or added (a column
/// named in `accepted_added` may be added: a later release's declared change; so may a row
/// named there as `row:CELL,CELL…`, a row whose first cells are those — a codebook's row for
/// an added column —, which is then left out before the rows are compared; and a row named
/// `changed:CELL,CELL…` may differ, left out of both), columns that
/// moved or changed type, the number of rows, and the first differing cells with their row.
/// Every column but the accepted ones must then be equal cell for cell; CSV also byte for
/// byte once those are left out, while Parquet may differ in the writer's own bytes
/// (`created_by`, page layout) when columns, types and every value are the same.
pub fn compare(
    file: &str,
    stored: &[u8],
    now: &[u8],
    accepted_added: &[String],
) -> Result<(), String> {
    if stored == now {
        return Ok(());
    }
    let format = Format::of(file);
    let read = |b: &[u8], which: &str| {
        Table::read(b, format)
            .map_err(|e| format!("{file}: the {which} export cannot be read: {e}"))
    };
    let (mut old, mut new) = (read(stored, "stored")?, read(now, "new")?);
    let keys = |prefix: &str| -> Vec<Vec<&str>> {
        accepted_added
            .iter()
            .filter_map(|a| a.strip_prefix(prefix))
            .map(|key| key.split(',').collect())
            .collect()
    };
    let named = |keys: &[Vec<&str>], r: &[Option<String>]| {
        keys.iter().any(|key| {
            key.len() <= r.len() && key.iter().zip(r).all(|(k, c)| c.as_deref() == Some(*k))
        })
    };
    // A row a later release reworded on purpose (`changed:CELL,CELL…`: a codebook row whose
    // meaning now names a new value) is left out of both before the rows are compared.
    let changed = keys("changed:");
    old.rows.retain(|r| !named(&changed, r));
    new.rows.retain(|r| !named(&changed, r));
    let accepted_rows = keys("row:");
    let rows_now = new.rows.len();
    new.rows.retain(|r| !named(&accepted_rows, r));
    let rows_added = rows_now - new.rows.len();
    let mut problems = Vec::new();
    let old_set: BTreeSet<&String> = old.columns.iter().collect();
    let new_set: BTreeSet<&String> = new.columns.iter().collect();
    let removed: Vec<&&String> = old_set.difference(&new_set).collect();
    if !removed.is_empty() {
        problems.push(format!("columns removed: {removed:?}"));
    }
    let added: Vec<&String> = new_set.difference(&old_set).copied().collect();
    let undeclared: Vec<&&String> = added
        .iter()
        .filter(|c| !accepted_added.contains(c))
        .collect();
    if !undeclared.is_empty() {
        problems.push(format!(
            "columns added: {undeclared:?} (a release that adds a column on purpose declares it in the fixture's accepted-changes.txt: `{file} COLUMN`)"
        ));
    }
    // The columns both have, in the stored order.
    let kept: Vec<(usize, usize)> = old
        .columns
        .iter()
        .enumerate()
        .filter_map(|(i, c)| new.columns.iter().position(|n| n == c).map(|j| (i, j)))
        .collect();
    if kept.windows(2).any(|w| w[1].1 < w[0].1) {
        problems.push(format!(
            "columns reordered: stored {:?}, now {:?}",
            old.columns, new.columns
        ));
    }
    for &(i, j) in &kept {
        if old.types[i] != new.types[j] {
            problems.push(format!(
                "column {}: type {} stored, {} now",
                old.columns[i], old.types[i], new.types[j]
            ));
        }
    }
    if old.rows.len() != new.rows.len() {
        problems.push(format!(
            "{} rows stored, {} now",
            old.rows.len(),
            new.rows.len()
        ));
    }
    let shown = |c: &Option<String>| {
        c.as_deref()
            .map_or("null".to_string(), |s| format!("{s:?}"))
    };
    let mut differing = 0;
    let mut listed = Vec::new();
    for (r, (a, b)) in old.rows.iter().zip(&new.rows).enumerate() {
        for &(i, j) in &kept {
            let (x, y) = (a.get(i).cloned().flatten(), b.get(j).cloned().flatten());
            if x != y {
                differing += 1;
                if listed.len() < CELLS_LISTED {
                    // The row's first cells say which it is (study, trial, subject, …).
                    let key: Vec<String> = old
                        .columns
                        .iter()
                        .zip(a)
                        .take(3)
                        .map(|(c, v)| format!("{c} = {}", shown(v)))
                        .collect();
                    listed.push(format!(
                        "  row {} ({}): {}: stored {}, now {}",
                        r + 1,
                        key.join(", "),
                        old.columns[i],
                        shown(&x),
                        shown(&y)
                    ));
                }
            }
        }
    }
    if differing > 0 {
        problems.push(format!(
            "{differing} cell(s) differ in the columns both have; the first:\n{}",
            listed.join("\n")
        ));
    }
    if problems.is_empty() && added.is_empty() && rows_added == 0 && format == Format::Csv {
        let at = stored
            .iter()
            .zip(now)
            .position(|(a, b)| a != b)
            .unwrap_or(stored.len().min(now.len()));
        let around = |b: &[u8]| {
            String::from_utf8_lossy(&b[at.saturating_sub(20)..(at + 20).min(b.len())]).into_owned()
        };
        problems.push(format!(
            "every cell is equal but the bytes differ (quoting, line ends or a trailing line): first at byte {at}: stored …{:?}…, now …{:?}…",
            around(stored),
            around(now)
        ));
    }
    if problems.is_empty() {
        return Ok(());
    }
    Err(format!(
        "{file} differs from the stored export:\n- {}",
        problems.join("\n- ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_names_added_columns_and_differing_cells() {
        let stored = b"id,a,b\n1,x,2\n2,y,3\n";
        assert_eq!(compare("t.csv", stored, stored, &[]), Ok(()));
        let added = b"id,a,site,b\n1,x,lab1,2\n2,y,lab1,3\n";
        let e = compare("t.csv", stored, added, &[]).unwrap_err();
        assert!(e.contains("columns added: [\"site\"]"), "{e}");
        assert_eq!(compare("t.csv", stored, added, &["site".into()]), Ok(()));
        let changed = b"id,a,b\n1,x,2\n2,z,3\n";
        let e = compare("t.csv", stored, changed, &[]).unwrap_err();
        assert!(
            e.contains("row 2 (id = \"2\", a = \"y\", b = \"3\"): a: stored \"y\", now \"z\""),
            "{e}"
        );
        let quoted = b"id,a,b\n1,\"x\",2\n2,y,3\n";
        let e = compare("t.csv", stored, quoted, &[]).unwrap_err();
        assert!(
            e.contains("every cell is equal but the bytes differ"),
            "{e}"
        );
        let more = b"id,a,b\n1,x,2\n2,y,3\n9,site,lab\n";
        let e = compare("t.csv", stored, more, &[]).unwrap_err();
        assert!(e.contains("2 rows stored, 3 now"), "{e}");
        assert_eq!(
            compare("t.csv", stored, more, &["row:9,site".into()]),
            Ok(())
        );
        let fewer = b"id,a\n1,x\n2,y\n3,w\n";
        let e = compare("t.csv", stored, fewer, &[]).unwrap_err();
        assert!(
            e.contains("columns removed: [\"b\"]") && e.contains("2 rows stored, 3 now"),
            "{e}"
        );
    }
}
