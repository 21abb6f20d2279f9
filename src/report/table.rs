//! A table for a results folder: named columns of text or numbers.

use super::stats::mean_ci95;

/// A table for a results folder: named columns of text or numbers.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub columns: Vec<(String, TableColumn)>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum TableColumn {
    Text(Vec<String>),
    Number(Vec<f64>),
    Count(Vec<u64>),
    Flag(Vec<bool>),
    /// A vector of numbers per row (a node's appearance).
    Vectors(Vec<Vec<f32>>),
}

impl Table {
    pub fn text(&mut self, name: &str, v: Vec<String>) {
        self.columns.push((name.into(), TableColumn::Text(v)));
    }

    pub fn number(&mut self, name: &str, v: Vec<f64>) {
        self.columns.push((name.into(), TableColumn::Number(v)));
    }

    pub fn count(&mut self, name: &str, v: Vec<u64>) {
        self.columns.push((name.into(), TableColumn::Count(v)));
    }

    /// Adds `name` and `name_ci95`: per row, the mean of its per-run
    /// samples and the half-width of the 95% interval. Undefined (NaN)
    /// samples are left out.
    pub fn stat(&mut self, name: &str, samples: &[Vec<f64>]) {
        let (m, c): (Vec<f64>, Vec<f64>) = samples.iter().map(|s| mean_ci95(s)).unzip();
        self.number(name, m);
        self.number(&format!("{name}_ci95"), c);
    }

    /// Adds `name`: per row, how many of its per-run samples are defined.
    pub fn defined(&mut self, name: &str, samples: &[Vec<f64>]) {
        let n = samples
            .iter()
            .map(|s| s.iter().filter(|x| x.is_finite()).count() as u64)
            .collect();
        self.count(name, n);
    }

    /// The column `name`, if it exists.
    pub fn column(&self, name: &str) -> Option<&TableColumn> {
        self.columns.iter().find(|(n, _)| n == name).map(|(_, c)| c)
    }

    pub fn height(&self) -> usize {
        match self.columns.first() {
            Some((_, TableColumn::Text(v))) => v.len(),
            Some((_, TableColumn::Number(v))) => v.len(),
            Some((_, TableColumn::Count(v))) => v.len(),
            Some((_, TableColumn::Flag(v))) => v.len(),
            Some((_, TableColumn::Vectors(v))) => v.len(),
            None => 0,
        }
    }
}
