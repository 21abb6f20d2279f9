//! The values of a dataset's rows, checked once where they are read, so
//! that nothing downstream meets a value it cannot use: every number
//! finite (NaN only where the schema gives it a meaning: a heading and
//! speed not reported, the true position of a false positive), every
//! accuracy and size >= 0, every covariance positive definite, colours in
//! [0, 1], positions within reach, classes coid knows. A row that breaks
//! one is refused with its file, row and column.

use super::read::DatasetError;
use super::schema::{Instance, Node, Truth};

/// How far from its vehicle a detection may be, body frame (no camera or
/// lidar sees 100 km).
const BODY_REACH_M: f64 = 1e5;

/// How far from the origin a world position may be (UTM northings are
/// below 1e7 m).
const WORLD_REACH_M: f64 = 1e8;

/// The refusal of `value` in row `row` (0-based) of `file`, column
/// `column`.
fn bad(
    file: &str,
    row: usize,
    column: &str,
    value: impl std::fmt::Display,
    why: &str,
) -> DatasetError {
    DatasetError {
        file: file.to_owned(),
        why: format!("row {}, column '{column}': {value} {why}", row + 1),
    }
}

/// A number as a message shows it: in scientific notation when huge or
/// tiny (never 300 digits).
fn num(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-4..1e7).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// `v` finite and within `reach` of 0.
fn within(file: &str, row: usize, column: &str, v: f64, reach: f64) -> Result<(), DatasetError> {
    if !v.is_finite() {
        return Err(bad(
            file,
            row,
            column,
            num(v),
            "is not a number coid can use (finite)",
        ));
    }
    if v.abs() > reach {
        return Err(bad(
            file,
            row,
            column,
            num(v),
            &format!("is farther than {reach:e} m: not a position coid can use"),
        ));
    }
    Ok(())
}

/// `v` finite and >= 0.
fn non_negative(file: &str, row: usize, column: &str, v: f64) -> Result<(), DatasetError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(bad(
            file,
            row,
            column,
            num(v),
            "is not a finite number >= 0",
        ))
    }
}

/// An instance row: finite poses, accuracies >= 0.
pub(super) fn instance(r: &Instance, row: usize) -> Result<(), DatasetError> {
    let f = Instance::FILE;
    if let Some(t) = r.time_s {
        within(f, row, "time_s", t, f64::MAX)?;
    }
    let poses = [
        ("first_x_m", r.first_x_m, WORLD_REACH_M),
        ("first_y_m", r.first_y_m, WORLD_REACH_M),
        ("first_heading_rad", r.first_heading_rad, 1e3),
        ("second_x_m", r.second_x_m, WORLD_REACH_M),
        ("second_y_m", r.second_y_m, WORLD_REACH_M),
        ("second_heading_rad", r.second_heading_rad, 1e3),
        ("first_true_x_m", r.first_true_x_m, WORLD_REACH_M),
        ("first_true_y_m", r.first_true_y_m, WORLD_REACH_M),
        ("first_true_heading_rad", r.first_true_heading_rad, 1e3),
        ("second_true_x_m", r.second_true_x_m, WORLD_REACH_M),
        ("second_true_y_m", r.second_true_y_m, WORLD_REACH_M),
        ("second_true_heading_rad", r.second_true_heading_rad, 1e3),
    ];
    for (column, v, reach) in poses {
        if let Some(v) = v {
            within(f, row, column, v, reach)?;
        }
    }
    non_negative(f, row, "position_sigma_m", r.position_sigma_m)?;
    non_negative(f, row, "first_heading_sigma_rad", r.first_heading_sigma_rad)?;
    non_negative(
        f,
        row,
        "second_heading_sigma_rad",
        r.second_heading_sigma_rad,
    )
}

/// A node row: what the matchers read of it.
pub(super) fn node(n: &Node, row: usize) -> Result<(), DatasetError> {
    let f = Node::FILE;
    within(f, row, "x_m", n.x_m, BODY_REACH_M)?;
    within(f, row, "y_m", n.y_m, BODY_REACH_M)?;
    if let Err(why) = crate::label::parse::<crate::traffic::ObjectClass>("object class", &n.class) {
        return Err(bad(
            f,
            row,
            "class",
            format!("'{}'", n.class),
            &format!("is not a class: {why}"),
        ));
    }
    if let (Some(xx), Some(xy), Some(yy)) = (n.cov_xx_m2, n.cov_xy_m2, n.cov_yy_m2) {
        let finite = xx.is_finite() && xy.is_finite() && yy.is_finite();
        if !(finite && xx > 0.0 && yy > 0.0 && xy * xy < xx * yy) {
            return Err(bad(
                f,
                row,
                "cov_xx_m2, cov_xy_m2, cov_yy_m2",
                format!("({xx}, {xy}, {yy})"),
                "is not a covariance (finite, positive definite)",
            ));
        }
    }
    for (column, v) in [
        ("colour_r", n.colour_r),
        ("colour_g", n.colour_g),
        ("colour_b", n.colour_b),
    ] {
        if let Some(v) = v
            && !(0.0..=1.0).contains(&v)
        {
            return Err(bad(f, row, column, v, "is not a colour value in [0, 1]"));
        }
    }
    for (column, v) in [
        ("length_m", n.length_m),
        ("width_m", n.width_m),
        ("height_m", n.height_m),
    ] {
        if let Some(v) = v {
            non_negative(f, row, column, v)?;
        }
    }
    motion(n, row)?;
    if let (Some(x), Some(y)) = (n.world_x_m, n.world_y_m) {
        within(f, row, "world_x_m", x, WORLD_REACH_M)?;
        within(f, row, "world_y_m", y, WORLD_REACH_M)?;
    }
    if let Some(a) = &n.appearance
        && let Some(k) = a.iter().position(|v| !v.is_finite())
    {
        return Err(bad(
            f,
            row,
            "appearance",
            a[k],
            &format!("at position {k} is not a number coid can use (finite)"),
        ));
    }
    Ok(())
}

/// A node's heading and speed: both finite (speed >= 0), or both NaN
/// (none reported).
fn motion(n: &Node, row: usize) -> Result<(), DatasetError> {
    let f = Node::FILE;
    match (n.heading_rad, n.speed_mps) {
        (Some(h), Some(s)) if h.is_nan() && s.is_nan() => Ok(()),
        (h, s) => {
            if let Some(h) = h {
                within(f, row, "heading_rad", h, 1e3)?;
            }
            if let Some(s) = s {
                non_negative(f, row, "speed_mps", s)?;
            }
            Ok(())
        }
    }
}

/// A truth row: a true position both finite or both NaN (none: a false
/// positive), a visible fraction in [0, 1].
pub(super) fn truth(t: &Truth, row: usize) -> Result<(), DatasetError> {
    let f = Truth::FILE;
    match (t.true_x_m, t.true_y_m) {
        (Some(x), Some(y)) if x.is_nan() && y.is_nan() => {}
        (x, y) => {
            if let Some(x) = x {
                within(f, row, "true_x_m", x, WORLD_REACH_M)?;
            }
            if let Some(y) = y {
                within(f, row, "true_y_m", y, WORLD_REACH_M)?;
            }
        }
    }
    if let Some(v) = t.visible_fraction
        && !(0.0..=1.0).contains(&v)
    {
        return Err(bad(
            f,
            row,
            "visible_fraction",
            v,
            "is not a fraction in [0, 1]",
        ));
    }
    Ok(())
}
