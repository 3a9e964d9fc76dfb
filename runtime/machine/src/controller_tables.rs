//! The text of controller compensation files, from tables already computed in SI
//! ([`crate::axis_table`], [`crate::component_errors`]). Each writer follows the format's own
//! documentation (spec/compensation.md says what each fixes and where kin had to assume); the
//! values' meaning and sign are decided by the callers' tables, the units and layout here.
//!
//! - SINUMERIK 840D: leadscrew error compensation (`$AA_ENC_COMP…`) and sag / cross-error
//!   compensation (`$AN_CEC…`) as part programs that set the system variables.
//! - ISG kernel (Beckhoff TwinCAT CNC): a bilateral leadscrew error compensation list
//!   (`kw.ssfk.*`), integers in 0.1 µm (0.0001° for rotary axes).
//! - ISG / Beckhoff VolComp: ISO 230-1 component errors in the "ISG CSV" format, values in mm
//!   and rad, the axis position in mm or degrees.

use crate::axis_table::AxisTable;
use crate::component_errors::ComponentTable;

/// How an axis's positions and corrections are written: millimetres, or degrees for a rotary
/// axis (the unit every one of these formats uses, whatever the model's own units).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum AxisUnit {
    Millimetre,
    Degree,
}

impl AxisUnit {
    pub fn of(kind: kin_compiler::ir::JointKind) -> AxisUnit {
        match kind {
            kin_compiler::ir::JointKind::Prismatic => AxisUnit::Millimetre,
            kin_compiler::ir::JointKind::Revolute => AxisUnit::Degree,
        }
    }

    /// `v` in SI (m or rad), in this unit.
    pub fn of_si(self, v: f64) -> f64 {
        match self {
            AxisUnit::Millimetre => v * 1e3,
            AxisUnit::Degree => v.to_degrees(),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            AxisUnit::Millimetre => "mm",
            AxisUnit::Degree => "deg",
        }
    }
}

/// A number with at most `decimals` decimals, trailing zeros dropped, never an exponent (a
/// controller's reader of decimal numbers need not know one) and never `-0`.
pub fn fixed(v: f64, decimals: usize) -> String {
    let text = format!("{v:.decimals$}");
    let text = if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    };
    if text == "-0" {
        "0".to_string()
    } else {
        text
    }
}

/// Comment lines in a format's comment syntax (`prefix` then a space), one per line of
/// `comments`.
fn comment_block(out: &mut String, prefix: &str, comments: &[String]) {
    for line in comments.iter().flat_map(|c| c.lines()) {
        out.push_str(prefix);
        if !line.is_empty() {
            out.push(' ');
            out.push_str(line);
        }
        out.push('\n');
    }
}

/// Decimals written for a position or correction in mm or degrees: 1e-9 of the unit (a
/// picometre), far below any controller's resolution, so the file is not where precision is
/// lost.
const DECIMALS: usize = 9;

/// One SINUMERIK leadscrew error compensation table: axis `name`'s `values` (mm or degrees,
/// the table's sign already applied) at equidistant positions from `min` in steps of `step`.
pub(crate) struct SinumerikLec<'a> {
    pub name: &'a str,
    pub min: f64,
    pub step: f64,
    pub values: Vec<f64>,
}

/// The part program `%_N_AX_EEC_INI` setting the leadscrew error compensation tables: per
/// axis `$AA_ENC_COMP[0,N,AXIS]` (measuring system 0, interpolation point N), and the table's
/// `_STEP`, `_MIN`, `_MAX` and `_IS_MODULO`, ended by `M17`.
pub(crate) fn sinumerik_lec(tables: &[SinumerikLec<'_>], comments: &[String]) -> String {
    let mut out = String::from("%_N_AX_EEC_INI\n");
    comment_block(&mut out, ";", comments);
    out.push_str("CHANDATA(1)\n");
    for t in tables {
        for (n, v) in t.values.iter().enumerate() {
            out.push_str(&format!(
                "$AA_ENC_COMP[0,{n},{}]={}\n",
                t.name,
                fixed(*v, DECIMALS)
            ));
        }
        let max = t.min + t.step * t.values.len().saturating_sub(1) as f64;
        out.push_str(&format!(
            "$AA_ENC_COMP_STEP[0,{}]={}\n",
            t.name,
            fixed(t.step, DECIMALS)
        ));
        out.push_str(&format!(
            "$AA_ENC_COMP_MIN[0,{}]={}\n",
            t.name,
            fixed(t.min, DECIMALS)
        ));
        out.push_str(&format!(
            "$AA_ENC_COMP_MAX[0,{}]={}\n",
            t.name,
            fixed(max, DECIMALS)
        ));
        out.push_str(&format!("$AA_ENC_COMP_IS_MODULO[0,{}]=0\n", t.name));
    }
    out.push_str("M17\n");
    out
}

/// One SINUMERIK sag / cross-error compensation table: `output`'s `values` (its unit, sign
/// applied) over equidistant positions of `input` from `min` in steps of `step`, for the
/// input axis's direction `direction` (0 both, 1 positive, −1 negative).
pub(crate) struct SinumerikCec<'a> {
    pub input: &'a str,
    pub output: &'a str,
    pub min: f64,
    pub step: f64,
    pub direction: i8,
    pub values: Vec<f64>,
}

/// The part program `%_N_NC_CEC_INI` setting the tables `$AN_CEC[t,N]` with their input and
/// output axes, `_STEP`, `_MIN`, `_MAX`, `_DIRECTION`, `_MULT_BY_TABLE` (0: none) and
/// `_IS_MODULO`, numbered from 0 in the order given, ended by `M17`.
pub(crate) fn sinumerik_cec(tables: &[SinumerikCec<'_>], comments: &[String]) -> String {
    let mut out = String::from("%_N_NC_CEC_INI\n");
    comment_block(&mut out, ";", comments);
    out.push_str("CHANDATA(1)\n");
    for (t, table) in tables.iter().enumerate() {
        for (n, v) in table.values.iter().enumerate() {
            out.push_str(&format!("$AN_CEC[{t},{n}]={}\n", fixed(*v, DECIMALS)));
        }
        let max = table.min + table.step * table.values.len().saturating_sub(1) as f64;
        out.push_str(&format!("$AN_CEC_INPUT_AXIS[{t}]=({})\n", table.input));
        out.push_str(&format!("$AN_CEC_OUTPUT_AXIS[{t}]=({})\n", table.output));
        out.push_str(&format!(
            "$AN_CEC_STEP[{t}]={}\n",
            fixed(table.step, DECIMALS)
        ));
        out.push_str(&format!(
            "$AN_CEC_MIN[{t}]={}\n",
            fixed(table.min, DECIMALS)
        ));
        out.push_str(&format!("$AN_CEC_MAX[{t}]={}\n", fixed(max, DECIMALS)));
        out.push_str(&format!("$AN_CEC_DIRECTION[{t}]={}\n", table.direction));
        out.push_str(&format!("$AN_CEC_MULT_BY_TABLE[{t}]=0\n"));
        out.push_str(&format!("$AN_CEC_IS_MODULO[{t}]=0\n"));
    }
    out.push_str("M17\n");
    out
}

/// Increments of an ISG compensation list per SI unit: 0.1 µm per metre for a linear axis,
/// 0.0001° per radian for a rotary one.
pub(crate) fn isg_increments(unit: AxisUnit) -> f64 {
    match unit {
        AxisUnit::Millimetre => 1e7,
        AxisUnit::Degree => 1e4 * 180.0 / std::f64::consts::PI,
    }
}

/// A position (SI) as a whole number of an ISG list's increments, `None` when it is not one
/// (up to rounding) or does not fit the list's 32-bit integers.
pub(crate) fn isg_position(si: f64, unit: AxisUnit) -> Option<i64> {
    let v = si * isg_increments(unit);
    let r = v.round();
    ((v - r).abs() <= 1e-6 + 1e-12 * r.abs() && r.abs() < f64::from(i32::MAX)).then_some(r as i64)
}

/// An ISG leadscrew error compensation list (`achskw*.lis`), bilateral, non-equidistant,
/// metric: for each nominal position `kw.ssfk.table[i].setpoint` and the deviations
/// `actual − setpoint` reached moving in + (`.pos`) and in − (`.neg`), all integers in 0.1 µm
/// (0.0001°). `table` holds corrections to add to the command (SI), so a deviation is the
/// negated correction. `None` when a nominal position is not a whole number of increments
/// (the list cannot state it).
pub(crate) fn isg_lsec(
    logical_axis: usize,
    name: &str,
    unit: AxisUnit,
    table: &AxisTable,
    comments: &[String],
) -> Option<String> {
    let per = isg_increments(unit);
    let round = |si: f64| (si * per).round() as i64;
    let setpoints: Vec<i64> = table
        .nominal
        .iter()
        .map(|p| isg_position(*p, unit))
        .collect::<Option<_>>()?;
    let mut out = String::new();
    comment_block(&mut out, "#", comments);
    out.push_str(&format!("kopf.achs_nr                 {logical_axis}\n"));
    out.push_str(&format!("kopf.log_achs_name           {name}\n"));
    out.push_str("kw.ssfk.interval             0\n");
    out.push_str(&format!(
        "kw.ssfk.kw_startpos          {}\n",
        setpoints.first().copied().unwrap_or(0)
    ));
    out.push_str(&format!(
        "kw.ssfk.kw_nr_max            {}\n",
        setpoints.len()
    ));
    out.push_str("kw.ssfk.unit                 1\n");
    out.push_str("kw.ssfk.bilateral            1\n");
    for (i, s) in setpoints.iter().enumerate() {
        out.push_str(&format!("kw.ssfk.table[{i}].setpoint   {s}\n"));
    }
    for (i, c) in table.forward.iter().enumerate() {
        out.push_str(&format!("kw.ssfk.table[{i}].pos        {}\n", round(-c)));
    }
    for (i, c) in table.reverse.iter().enumerate() {
        out.push_str(&format!("kw.ssfk.table[{i}].neg        {}\n", round(-c)));
    }
    out.push_str("End\n");
    Some(out)
}

/// ISO 230-1 letters of the six component errors, in `(tx, ty, tz, rx, ry, rz)` order.
pub(crate) const ISO_DIRECTIONS: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// One axis's component errors in the ISG CSV format: a header `AXIS EXAXIS EYAXIS … ECAXIS`
/// (the argument, then the parameters), one record per position separated by spaces; the
/// position in mm or degrees, translations in mm, rotations in rad; `//` comments.
pub(crate) fn volcomp_csv(
    name: &str,
    unit: AxisUnit,
    table: &ComponentTable,
    comments: &[String],
) -> String {
    let mut out = String::new();
    comment_block(&mut out, "//", comments);
    out.push_str(name);
    for d in ISO_DIRECTIONS {
        out.push_str(&format!(" E{d}{name}"));
    }
    out.push('\n');
    for (p, v) in table.nominal.iter().zip(&table.values) {
        out.push_str(&fixed(unit.of_si(*p), DECIMALS));
        for (k, x) in v.iter().enumerate() {
            // Translations in mm to the picometre, rotations in rad to the picoradian.
            let (value, decimals) = if k < 3 { (x * 1e3, 9) } else { (*x, 12) };
            out.push(' ');
            out.push_str(&fixed(value, decimals));
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> AxisTable {
        AxisTable {
            axis: 0,
            nominal: vec![-0.02, 0.0, 0.02],
            forward: vec![1e-6, 0.0, -2.5e-6],
            reverse: vec![3e-6, 2e-6, -0.5e-6],
            interpolation_error: 0.0,
        }
    }

    #[test]
    fn numbers_are_fixed_point() {
        assert_eq!(fixed(0.0000123, 9), "0.0000123");
        assert_eq!(fixed(-0.0000000001, 9), "0");
        assert_eq!(fixed(250.0, 9), "250");
        assert_eq!(fixed(-1.5, 9), "-1.5");
    }

    #[test]
    fn isg_list_deviations_are_negated_corrections_in_tenths_of_a_micrometre() {
        let text = isg_lsec(2, "Y", AxisUnit::Millimetre, &table(), &["kin".into()])
            .expect("whole increments");
        assert!(text.starts_with("# kin\n"), "{text}");
        assert!(
            text.contains("kw.ssfk.table[0].setpoint   -200000\n"),
            "{text}"
        );
        assert!(text.contains("kw.ssfk.table[2].pos        25\n"), "{text}");
        assert!(text.contains("kw.ssfk.table[1].neg        -20\n"), "{text}");
        assert!(text.ends_with("End\n"));
        let mut off = table();
        off.nominal[1] = 0.000_000_05;
        assert!(isg_lsec(2, "Y", AxisUnit::Millimetre, &off, &[]).is_none());
    }

    #[test]
    fn sinumerik_programs_open_with_their_name_and_end_with_m17() {
        let lec = sinumerik_lec(
            &[SinumerikLec {
                name: "X1",
                min: -200.0,
                step: 1.0,
                values: vec![0.003, 0.01],
            }],
            &["from kin".into()],
        );
        assert_eq!(
            lec,
            "%_N_AX_EEC_INI\n; from kin\nCHANDATA(1)\n$AA_ENC_COMP[0,0,X1]=0.003\n$AA_ENC_COMP[0,1,X1]=0.01\n$AA_ENC_COMP_STEP[0,X1]=1\n$AA_ENC_COMP_MIN[0,X1]=-200\n$AA_ENC_COMP_MAX[0,X1]=-199\n$AA_ENC_COMP_IS_MODULO[0,X1]=0\nM17\n"
        );
        let cec = sinumerik_cec(
            &[SinumerikCec {
                input: "Y1",
                output: "Z1",
                min: 0.0,
                step: 50.0,
                direction: 0,
                values: vec![0.0, -0.002],
            }],
            &[],
        );
        assert!(
            cec.contains(
                "$AN_CEC[0,1]=-0.002\n$AN_CEC_INPUT_AXIS[0]=(Y1)\n$AN_CEC_OUTPUT_AXIS[0]=(Z1)\n"
            ),
            "{cec}"
        );
        assert!(cec.contains("$AN_CEC_MAX[0]=50\n"), "{cec}");
        assert!(cec.ends_with("M17\n"));
    }
}
