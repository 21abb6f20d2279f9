//! A dataset's files, one declaration each: a row struct whose fields are
//! the file's columns in order, each with its type (`u64`, `f64`, text as
//! `String`, `bool`, a vector as `Vec<f32>`; `Option<_>` for an optional
//! column, written only when every row has a value), and the table of such
//! rows ([`file_rows!`]). A column is named once, as a field: a misspelt
//! or missing one does not compile. The declarations are
//! `docs/export-schema.md`'s tables (a test compares them).

use crate::report::{Table, TableColumn};

/// A column's values as a table holds them, by their type; `None` for an
/// optional column that is not written (a row without a value).
pub(crate) trait ColumnValue: Sized {
    fn column(values: Vec<Self>) -> Option<TableColumn>;

    /// The values of a column read back (`None`: the table has no such
    /// column) for `rows` rows; `None` when a required column is missing
    /// or the column holds another type.
    fn values(column: Option<TableColumn>, rows: usize) -> Option<Vec<Self>>;
}

/// Each column type and the table column that holds it; an optional
/// column of it is written when every row has a value.
macro_rules! column_values {
    ($($ty:ty => $column:ident),+) => {
        $(impl ColumnValue for $ty {
            fn column(values: Vec<Self>) -> Option<TableColumn> {
                Some(TableColumn::$column(values))
            }

            fn values(column: Option<TableColumn>, _rows: usize) -> Option<Vec<Self>> {
                match column {
                    Some(TableColumn::$column(v)) => Some(v),
                    _ => None,
                }
            }
        }

        impl ColumnValue for Option<$ty> {
            fn column(values: Vec<Self>) -> Option<TableColumn> {
                let all: Option<Vec<$ty>> = values.into_iter().collect();
                all.map(TableColumn::$column)
            }

            fn values(column: Option<TableColumn>, rows: usize) -> Option<Vec<Self>> {
                match column {
                    None => Some(vec![None; rows]),
                    Some(TableColumn::$column(v)) => Some(v.into_iter().map(Some).collect()),
                    Some(_) => None,
                }
            }
        })+
    };
}

column_values!(u64 => Count, f64 => Number, String => Text, bool => Flag, Vec<f32> => Vectors);

/// Declares the rows of one file (`in "<file>"` when its name is fixed):
/// a struct with one field per column, in the file's column order, and
/// `table(rows)`, the rows as the file's table.
macro_rules! file_rows {
    (
        $(#[$meta:meta])*
        $row:ident $(in $file:literal)? {
            $($(#[$field_meta:meta])* $column:ident: $ty:ty,)+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq)]
        pub(crate) struct $row {
            $($(#[$field_meta])* pub $column: $ty,)+
        }

        impl $row {
            $(pub(crate) const FILE: &'static str = $file;)?

            /// The file's columns in order: name and declared type
            /// (`Option<..>`: optional).
            #[allow(dead_code, reason = "the matches file's are only documented")]
            pub(crate) const COLUMNS: &'static [(&'static str, &'static str)] =
                &[$((stringify!($column), stringify!($ty)),)+];

            /// `rows` as the file's table (an optional column only where
            /// every row has a value).
            pub(crate) fn table(rows: Vec<Self>) -> Table {
                $(let mut $column: Vec<$ty> = Vec::with_capacity(rows.len());)+
                for row in rows {
                    $($column.push(row.$column);)+
                }
                let mut table = Table::default();
                $(if let Some(c) = ColumnValue::column($column) {
                    table.columns.push((stringify!($column).to_owned(), c));
                })+
                table
            }

            /// The rows of a table read back with [`Self::COLUMNS`]
            /// (optional columns it lacks are `None` in every row).
            #[allow(dead_code, reason = "the matches file is read by its own reader")]
            pub(crate) fn rows(table: Table) -> Result<Vec<Self>, String> {
                let n = table.height();
                let mut columns: std::collections::BTreeMap<String, TableColumn> =
                    table.columns.into_iter().collect();
                $(let mut $column = <$ty as ColumnValue>::values(
                    columns.remove(stringify!($column)),
                    n,
                )
                .ok_or_else(|| format!(
                    "column '{}' is missing or not {}",
                    stringify!($column),
                    stringify!($ty)
                ))?
                .into_iter();)+
                Ok((0..n)
                    .map(|_| Self {
                        $($column: $column.next().expect("a value per row"),)+
                    })
                    .collect())
            }
        }
    };
}

file_rows! {
    /// A run: what it may be used for, where it comes from, its instances.
    Run in "runs.parquet" {
        schema_version: u64,
        run: u64,
        split: String,
        scenario: String,
        seed: u64,
        n_instances: u64,
        config_digest: String,
    }
}

file_rows! {
    /// An instance at one pose-noise level: the vehicles' reported poses
    /// (where the source gives them) and their true poses (where known).
    Instance in "instances.parquet" {
        run: u64,
        instance: u64,
        pose_noise: String,
        step: u64,
        time_s: Option<f64>,
        first_id: String,
        second_id: String,
        n_first: u64,
        n_second: u64,
        first_x_m: Option<f64>,
        first_y_m: Option<f64>,
        first_heading_rad: Option<f64>,
        second_x_m: Option<f64>,
        second_y_m: Option<f64>,
        second_heading_rad: Option<f64>,
        position_sigma_m: f64,
        first_heading_sigma_rad: f64,
        second_heading_sigma_rad: f64,
        first_true_x_m: Option<f64>,
        first_true_y_m: Option<f64>,
        first_true_heading_rad: Option<f64>,
        second_true_x_m: Option<f64>,
        second_true_y_m: Option<f64>,
        second_true_heading_rad: Option<f64>,
    }
}

file_rows! {
    /// A node of one vehicle of an instance: what its camera measured.
    Node in "nodes.parquet" {
        run: u64,
        instance: u64,
        side: u64,
        node: u64,
        x_m: f64,
        y_m: f64,
        cov_xx_m2: Option<f64>,
        cov_xy_m2: Option<f64>,
        cov_yy_m2: Option<f64>,
        class: String,
        colour_r: Option<f64>,
        colour_g: Option<f64>,
        colour_b: Option<f64>,
        length_m: Option<f64>,
        width_m: Option<f64>,
        height_m: Option<f64>,
        heading_rad: Option<f64>,
        speed_mps: Option<f64>,
        sender: Option<bool>,
        world_x_m: Option<f64>,
        world_y_m: Option<f64>,
        appearance: Option<Vec<f32>>,
    }
}

file_rows! {
    /// An edge of one vehicle's Delaunay graph, `source < target`.
    Edge in "edges.parquet" {
        run: u64,
        instance: u64,
        side: u64,
        source: u64,
        target: u64,
        length_m: f64,
    }
}

file_rows! {
    /// What lies behind a node.
    Truth in "truth.parquet" {
        run: u64,
        instance: u64,
        side: u64,
        node: u64,
        object_id: String,
        true_x_m: Option<f64>,
        true_y_m: Option<f64>,
        visible_fraction: Option<f64>,
    }
}

file_rows! {
    /// A true correspondence: node `a` of the first vehicle is node `b` of
    /// the second.
    TruePair in "true_pairs.parquet" {
        run: u64,
        instance: u64,
        a: u64,
        b: u64,
    }
}

file_rows! {
    /// A method's match at one level (`matches-<method>.parquet`).
    Match {
        run: u64,
        instance: u64,
        pose_noise: String,
        a: u64,
        b: u64,
        probability: f64,
        uncertainty: f64,
    }
}

/// Every file's name and columns, in the documented order (the matches
/// file as `matches-<method>.parquet`).
#[cfg(test)]
pub(crate) fn all_files() -> [(&'static str, &'static [(&'static str, &'static str)]); 7] {
    [
        (Run::FILE, Run::COLUMNS),
        (Instance::FILE, Instance::COLUMNS),
        (Node::FILE, Node::COLUMNS),
        (Edge::FILE, Edge::COLUMNS),
        (Truth::FILE, Truth::COLUMNS),
        (TruePair::FILE, TruePair::COLUMNS),
        ("matches-<method>.parquet", Match::COLUMNS),
    ]
}

#[cfg(test)]
mod tests {
    use super::all_files;
    use crate::dataset::SCHEMA;

    /// Each file's columns as `docs/export-schema.md` lists them: (file,
    /// [(column, type)]), an optional column's type as `Option<type>`.
    fn documented() -> Vec<(String, Vec<(String, String)>)> {
        let mut files: Vec<(String, Vec<(String, String)>)> = Vec::new();
        for line in SCHEMA.lines() {
            if let Some(heading) = line.strip_prefix("## `") {
                let file = heading.split('`').next().unwrap_or_default();
                files.push((file.to_owned(), Vec::new()));
                continue;
            }
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let is_matches = file_is_matches(files.last());
            let (Some(names), Some(types), Some((_, columns))) =
                (cells.get(1), cells.get(2), files.last_mut())
            else {
                continue;
            };
            if !names.starts_with('`') {
                continue;
            }
            let names: Vec<&str> = names.split('`').skip(1).step_by(2).collect();
            let optional = types.ends_with(", optional");
            let types: Vec<&str> = types.trim_end_matches(", optional").split(", ").collect();
            for (k, name) in names.iter().enumerate() {
                let ty = match types.get(k).or(types.first()).copied() {
                    Some("integer") => "u64",
                    Some("number") => "f64",
                    Some("text") => "String",
                    Some("f32 list") => "Vec<f32>",
                    Some(ty) => ty,
                    None => "",
                };
                // The matches file's optional columns are what `coid score`
                // reads; the export writes every one.
                let ty = if optional && !is_matches {
                    format!("Option<{ty}>")
                } else {
                    ty.to_owned()
                };
                columns.push(((*name).to_owned(), ty));
            }
        }
        files
    }

    fn file_is_matches(f: Option<&(String, Vec<(String, String)>)>) -> bool {
        f.is_some_and(|(name, _)| name.starts_with("matches-"))
    }

    /// Every file of a dataset has the columns, order, types and
    /// optionality the schema documents, and the schema documents no
    /// other file.
    #[test]
    fn the_files_are_the_documented_schema() {
        let declared: Vec<(String, Vec<(String, String)>)> = all_files()
            .iter()
            .map(|(file, columns)| {
                let c = columns
                    .iter()
                    .map(|(n, t)| ((*n).to_owned(), t.replace(' ', "")))
                    .collect();
                ((*file).to_owned(), c)
            })
            .collect();
        assert_eq!(declared, documented());
    }
}
