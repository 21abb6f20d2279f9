//! The export's files, one declaration each: a row struct whose fields are
//! the file's columns in order, each with its type (`u64`, `f64`, text as
//! `String`, `bool`), and the table of such rows ([`file_rows!`]). A column
//! is named once, as a field: a misspelt or missing one does not compile.
//! The declarations are `docs/export-schema.md`'s tables (a test compares
//! them).

use crate::report::{Table, TableColumn};

/// A column's values as a table holds them, by their type.
trait ColumnValue: Sized {
    fn column(values: Vec<Self>) -> TableColumn;
}

/// Each column type and the table column that holds it.
macro_rules! column_values {
    ($($ty:ty => $column:ident),+) => {
        $(impl ColumnValue for $ty {
            fn column(values: Vec<Self>) -> TableColumn {
                TableColumn::$column(values)
            }
        })+
    };
}

column_values!(u64 => Count, f64 => Number, String => Text, bool => Flag);

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
        pub(super) struct $row {
            $($(#[$field_meta])* pub $column: $ty,)+
        }

        impl $row {
            $(pub(super) const FILE: &'static str = $file;)?

            /// `rows` as the file's table.
            pub(super) fn table(rows: Vec<Self>) -> Table {
                $(let mut $column: Vec<$ty> = Vec::with_capacity(rows.len());)+
                for row in rows {
                    $($column.push(row.$column);)+
                }
                let mut table = Table::default();
                $(table
                    .columns
                    .push((stringify!($column).to_owned(), ColumnValue::column($column)));)+
                table
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
    /// An instance at one pose-noise level: the vehicles' reported poses.
    Instance in "instances.parquet" {
        run: u64,
        instance: u64,
        pose_noise: String,
        step: u64,
        time_s: f64,
        first_id: String,
        second_id: String,
        n_first: u64,
        n_second: u64,
        first_x_m: f64,
        first_y_m: f64,
        first_heading_rad: f64,
        second_x_m: f64,
        second_y_m: f64,
        second_heading_rad: f64,
        position_sigma_m: f64,
        first_heading_sigma_rad: f64,
        second_heading_sigma_rad: f64,
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
        cov_xx_m2: f64,
        cov_xy_m2: f64,
        cov_yy_m2: f64,
        class: String,
        colour_r: f64,
        colour_g: f64,
        colour_b: f64,
        length_m: f64,
        width_m: f64,
        height_m: f64,
        heading_rad: f64,
        speed_mps: f64,
        sender: bool,
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
        true_x_m: f64,
        true_y_m: f64,
        visible_fraction: f64,
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

#[cfg(test)]
mod tests {
    use crate::export::{SCHEMA, files, matches_template};
    use crate::report::{Table, TableColumn};

    /// Each file's columns as `docs/export-schema.md` lists them: (file,
    /// [(column, type)]), the matches file as `matches-<method>.parquet`.
    fn documented() -> Vec<(String, Vec<(String, String)>)> {
        let mut files: Vec<(String, Vec<(String, String)>)> = Vec::new();
        for line in SCHEMA.lines() {
            if let Some(heading) = line.strip_prefix("## `") {
                let file = heading.split('`').next().unwrap_or_default();
                files.push((file.to_owned(), Vec::new()));
                continue;
            }
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let (Some(names), Some(types), Some((_, columns))) =
                (cells.get(1), cells.get(2), files.last_mut())
            else {
                continue;
            };
            if !names.starts_with('`') {
                continue;
            }
            let names: Vec<&str> = names.split('`').skip(1).step_by(2).collect();
            let types: Vec<&str> = types.trim_end_matches(", optional").split(", ").collect();
            for (k, name) in names.iter().enumerate() {
                let ty = match types.get(k).or(types.first()).copied() {
                    Some("integer") => "u64",
                    Some("number") => "f64",
                    Some(ty) => ty,
                    None => "",
                };
                columns.push(((*name).to_owned(), ty.to_owned()));
            }
        }
        files
    }

    fn columns(t: &Table) -> Vec<(String, String)> {
        let ty = |c: &TableColumn| match c {
            TableColumn::Count(_) => "u64",
            TableColumn::Number(_) => "f64",
            TableColumn::Text(_) => "text",
            TableColumn::Flag(_) => "bool",
        };
        t.columns
            .iter()
            .map(|(name, c)| (name.clone(), ty(c).to_owned()))
            .collect()
    }

    /// Every file the export writes has the columns, order and types the
    /// schema documents, and the schema documents no other file.
    #[test]
    fn the_files_are_the_documented_schema() {
        let mut written: Vec<(String, Vec<(String, String)>)> = files()
            .iter()
            .map(|(file, t)| ((*file).to_owned(), columns(t)))
            .collect();
        written.push((
            "matches-<method>.parquet".to_owned(),
            columns(&matches_template()),
        ));
        assert_eq!(written, documented());
    }
}
