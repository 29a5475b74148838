//! Writing an export's rows as CSV or Parquet. Both read the export's column specs
//! (`columns`): CSV writes their names as the header and every number with the one
//! formatter at the column's resolution; Parquet makes them its schema and stores the same
//! rounded numbers, so a Parquet file holds exactly what the CSV says. Rows stream: CSV line
//! by line, Parquet in record batches and row groups of bounded size, its bytes passed on
//! as each row group is written, so memory stays bounded however large the study.

use std::borrow::Cow;
use std::sync::Arc;

use arrow_array::builder::{Float64Builder, Int64Builder, StringBuilder};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use bdft_protocol::numbers::{format_number, round_number};
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::properties::WriterProperties;
use tokio::io::{AsyncWrite, AsyncWriteExt};

use super::ExportError;
use super::columns::{Column, ColumnType};

/// The file format of an export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ExportFormat {
    #[default]
    Csv,
    Parquet,
}

impl ExportFormat {
    pub fn extension(self) -> &'static str {
        match self {
            Self::Csv => "csv",
            Self::Parquet => "parquet",
        }
    }

    pub fn mime(self) -> &'static str {
        match self {
            Self::Csv => "text/csv; charset=utf-8",
            Self::Parquet => "application/vnd.apache.parquet",
        }
    }
}

impl std::str::FromStr for ExportFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "csv" => Ok(Self::Csv),
            "parquet" => Ok(Self::Parquet),
            _ => Err(format!("unknown format {s:?}; allowed: csv, parquet")),
        }
    }
}

/// One cell: `Int` for integer and flag columns, `Num` for number columns, `Text` for text
/// and time columns; `None` is an empty cell (null in Parquet).
#[derive(Debug, Clone, PartialEq)]
pub enum Cell<'a> {
    Int(Option<i64>),
    Num(Option<f64>),
    Text(Option<Cow<'a, str>>),
}

impl<'a> Cell<'a> {
    pub fn text(s: impl Into<Cow<'a, str>>) -> Self {
        Self::Text(Some(s.into()))
    }
    pub fn flag(b: bool) -> Self {
        Self::Int(Some(i64::from(b)))
    }
}

/// Rows per Parquet record batch, and per row group (about 10 MB of samples in memory).
const BATCH_ROWS: usize = 8192;
const ROW_GROUP_ROWS: usize = 16 * BATCH_ROWS;

/// Writes rows of `columns` to `out` in `format`.
pub struct TableWriter<W> {
    columns: Vec<Column>,
    out: W,
    inner: Inner,
}

enum Inner {
    Csv { line: String },
    Parquet(Box<ParquetTable>),
}

impl<W> std::fmt::Debug for TableWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TableWriter")
            .field("columns", &self.columns.len())
            .finish()
    }
}

impl<W: AsyncWrite + Unpin> TableWriter<W> {
    /// Starts the table (the CSV header goes out at once).
    pub async fn start(
        columns: Vec<Column>,
        format: ExportFormat,
        mut out: W,
    ) -> Result<Self, ExportError> {
        let inner = match format {
            ExportFormat::Csv => {
                let header: Vec<String> =
                    columns.iter().map(|c| super::text_cell(&c.name)).collect();
                out.write_all(format!("{}\n", header.join(",")).as_bytes())
                    .await?;
                Inner::Csv {
                    line: String::with_capacity(256),
                }
            }
            ExportFormat::Parquet => Inner::Parquet(Box::new(ParquetTable::new(&columns)?)),
        };
        Ok(Self {
            columns,
            out,
            inner,
        })
    }

    pub fn columns(&self) -> &[Column] {
        &self.columns
    }

    /// One row, its cells in column order.
    pub async fn row(&mut self, cells: &[Cell<'_>]) -> Result<(), ExportError> {
        debug_assert_eq!(cells.len(), self.columns.len());
        match &mut self.inner {
            Inner::Csv { line } => {
                line.clear();
                for (i, (cell, column)) in cells.iter().zip(&self.columns).enumerate() {
                    if i > 0 {
                        line.push(',');
                    }
                    push_csv_cell(line, cell, column.ty);
                }
                line.push('\n');
                self.out.write_all(line.as_bytes()).await?;
            }
            Inner::Parquet(t) => {
                t.push(cells, &self.columns);
                if t.rows == BATCH_ROWS {
                    let bytes = t.write_batch()?;
                    self.out.write_all(&bytes).await?;
                }
            }
        }
        Ok(())
    }

    /// Ends the table (Parquet: the last row group and the footer) and flushes `out`.
    pub async fn finish(mut self) -> Result<(), ExportError> {
        if let Inner::Parquet(t) = self.inner {
            let bytes = t.close()?;
            self.out.write_all(&bytes).await?;
        }
        self.out.flush().await?;
        Ok(())
    }
}

/// A CSV cell: numbers by the one formatter at the column's resolution, text neutralized
/// against formula injection and quoted when needed.
fn push_csv_cell(line: &mut String, cell: &Cell<'_>, ty: ColumnType) {
    match cell {
        Cell::Int(Some(v)) => line.push_str(&v.to_string()),
        Cell::Num(Some(v)) => line.push_str(&format_number(*v, decimals(ty))),
        Cell::Text(Some(s)) => line.push_str(&super::text_cell(s)),
        Cell::Int(None) | Cell::Num(None) | Cell::Text(None) => {}
    }
}

fn decimals(ty: ColumnType) -> u8 {
    match ty {
        ColumnType::Number { decimals } => decimals,
        _ => 0,
    }
}

/// A Parquet table being written: one Arrow builder per column, flushed as a record batch
/// every `BATCH_ROWS` rows; the writer cuts row groups of `ROW_GROUP_ROWS`.
struct ParquetTable {
    schema: SchemaRef,
    builders: Vec<Builder>,
    rows: usize,
    writer: ArrowWriter<Vec<u8>>,
}

enum Builder {
    Int(Int64Builder),
    Num(Float64Builder),
    Text(StringBuilder),
}

impl ParquetTable {
    fn new(columns: &[Column]) -> Result<Self, ExportError> {
        let fields: Vec<Field> = columns
            .iter()
            .map(|c| {
                let ty = match c.ty {
                    ColumnType::Integer | ColumnType::Flag => DataType::Int64,
                    ColumnType::Number { .. } => DataType::Float64,
                    ColumnType::Text | ColumnType::Time => DataType::Utf8,
                };
                Field::new(c.name.as_ref(), ty, true)
            })
            .collect();
        let schema = Arc::new(Schema::new(fields));
        let props = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_max_row_group_size(ROW_GROUP_ROWS)
            .build();
        let writer = ArrowWriter::try_new(Vec::new(), schema.clone(), Some(props))?;
        let mut t = Self {
            schema,
            builders: Vec::new(),
            rows: 0,
            writer,
        };
        t.builders = t.new_builders(columns);
        Ok(t)
    }

    fn new_builders(&self, columns: &[Column]) -> Vec<Builder> {
        columns
            .iter()
            .map(|c| match c.ty {
                ColumnType::Integer | ColumnType::Flag => {
                    Builder::Int(Int64Builder::with_capacity(BATCH_ROWS))
                }
                ColumnType::Number { .. } => {
                    Builder::Num(Float64Builder::with_capacity(BATCH_ROWS))
                }
                ColumnType::Text | ColumnType::Time => Builder::Text(StringBuilder::new()),
            })
            .collect()
    }

    /// Text is stored as given (no spreadsheet reads Parquet); numbers as the CSV writes
    /// them (`round_number`).
    fn push(&mut self, cells: &[Cell<'_>], columns: &[Column]) {
        for ((b, cell), column) in self.builders.iter_mut().zip(cells).zip(columns) {
            match (b, cell) {
                (Builder::Int(b), Cell::Int(v)) => b.append_option(*v),
                (Builder::Num(b), Cell::Num(v)) => {
                    b.append_option(v.map(|x| round_number(x, decimals(column.ty))))
                }
                (Builder::Text(b), Cell::Text(v)) => b.append_option(v.as_deref()),
                (b, _) => {
                    // A cell of the wrong kind is a bug in the export; it is written empty.
                    debug_assert!(false, "cell {cell:?} in column {}", column.name);
                    match b {
                        Builder::Int(b) => b.append_null(),
                        Builder::Num(b) => b.append_null(),
                        Builder::Text(b) => b.append_null(),
                    }
                }
            }
        }
        self.rows += 1;
    }

    /// Hands the buffered rows to the writer; returns the bytes it has written since the
    /// last call (row groups as they complete).
    fn write_batch(&mut self) -> Result<Vec<u8>, ExportError> {
        if self.rows > 0 {
            let arrays: Vec<ArrayRef> = self
                .builders
                .iter_mut()
                .map(|b| -> ArrayRef {
                    match b {
                        Builder::Int(b) => Arc::new(b.finish()),
                        Builder::Num(b) => Arc::new(b.finish()),
                        Builder::Text(b) => Arc::new(b.finish()),
                    }
                })
                .collect();
            let batch = RecordBatch::try_new(self.schema.clone(), arrays)
                .map_err(parquet::errors::ParquetError::from)?;
            self.writer.write(&batch)?;
            self.rows = 0;
        }
        // Only the writer's finished bytes are taken; it counts its offsets itself.
        Ok(std::mem::take(self.writer.inner_mut()))
    }

    fn close(mut self) -> Result<Vec<u8>, ExportError> {
        let mut bytes = self.write_batch()?;
        bytes.extend(self.writer.into_inner()?);
        Ok(bytes)
    }
}
