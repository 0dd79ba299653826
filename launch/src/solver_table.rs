//! `dc eval --solvers` and `dc eval --budget`: the solver x model and budget x model tables, from
//! each evaluation's report (`summary.csv`, as the metrics node writes it).

/// What the table reads of one model's row of a `summary.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryRow {
    pub model: String,
    pub total_sweeps: u64,
    pub total_solve_ms: f64,
    pub cap_hits: u64,
    /// Same states vs builtin within the solver's evaluation (NaN where not measured).
    pub same_states: f64,
    /// The median critical path (warm start + solve) over the steps with contacts, us (NaN where
    /// the report predates the column).
    pub median_critical_us: f64,
    /// Accuracy (NaN where the report predates the columns): the mean RMS natural residual, the
    /// mean largest penetration, the late phase's mean kinetic energy.
    pub natural_rms: f64,
    pub penetration_max: f64,
    pub late_kinetic_energy: f64,
    /// The warm-start error split (`dc eval --error-split`): the share of builtin's smooth and
    /// rough error the model's start removes, and the RMS error the budget's sweeps leave from
    /// the model's start and from builtin's (NaN where not measured).
    pub smooth_removed: f64,
    pub rough_removed: f64,
    pub left_rms: f64,
    pub builtin_left_rms: f64,
    /// The RMS natural residual the budget's sweeps leave from each start on the same steps.
    pub left_natural: f64,
    pub builtin_left_natural: f64,
}

/// A `summary.csv` that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum SummaryError {
    #[error("no header line")]
    Empty,
    #[error("column `{0}` is missing")]
    MissingColumn(&'static str),
    #[error("line {line}: column `{column}`: `{value}` is not a number")]
    BadNumber { line: usize, column: &'static str, value: String },
    #[error("line {line}: {found} fields, the header has {expected}")]
    Ragged { line: usize, found: usize, expected: usize },
}

const COLUMNS: [&str; 5] = ["model", "total_sweeps", "total_solve_ms", "cap_hits", "same_states_ratio_to_builtin"];

/// Columns read when present (reports written before them lack them; the split's are empty
/// where not measured).
const ACCURACY_COLUMNS: [&str; 10] = [
    "median_critical_us",
    "mean_natural_rms",
    "mean_penetration_max",
    "late_kinetic_energy",
    "split_smooth_removed",
    "split_rough_removed",
    "split_left_rms",
    "split_builtin_left_rms",
    "split_left_natural",
    "split_builtin_left_natural",
];

/// Reads the rows of a `summary.csv`.
pub fn read_summary(text: &str) -> Result<Vec<SummaryRow>, SummaryError> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().ok_or(SummaryError::Empty)?.split(',').collect();
    let mut at = [0usize; COLUMNS.len()];
    for (slot, name) in at.iter_mut().zip(COLUMNS) {
        *slot = header.iter().position(|h| *h == name).ok_or(SummaryError::MissingColumn(name))?;
    }
    let optional: Vec<Option<usize>> =
        ACCURACY_COLUMNS.iter().map(|name| header.iter().position(|h| h == name)).collect();
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let fields: Vec<&str> = line.split(',').collect();
        let line = i + 2;
        if fields.len() != header.len() {
            return Err(SummaryError::Ragged { line, found: fields.len(), expected: header.len() });
        }
        let number = |k: usize| {
            fields[at[k]].parse::<f64>().map_err(|_| SummaryError::BadNumber {
                line,
                column: COLUMNS[k],
                value: fields[at[k]].to_string(),
            })
        };
        // An empty cell is a figure the report could not compute (no step with contacts).
        let accuracy = |k: usize| match optional[k] {
            None => Ok(f64::NAN),
            Some(at) if fields[at].is_empty() => Ok(f64::NAN),
            Some(at) => fields[at].parse::<f64>().map_err(|_| SummaryError::BadNumber {
                line,
                column: ACCURACY_COLUMNS[k],
                value: fields[at].to_string(),
            }),
        };
        rows.push(SummaryRow {
            model: fields[at[0]].to_string(),
            total_sweeps: number(1)? as u64,
            total_solve_ms: number(2)?,
            cap_hits: number(3)? as u64,
            // Empty where not measured (`--same-states false`, or at a budget).
            same_states: if fields[at[4]].is_empty() { f64::NAN } else { number(4)? },
            median_critical_us: accuracy(0)?,
            natural_rms: accuracy(1)?,
            penetration_max: accuracy(2)?,
            late_kinetic_energy: accuracy(3)?,
            smooth_removed: accuracy(4)?,
            rough_removed: accuracy(5)?,
            left_rms: accuracy(6)?,
            builtin_left_rms: accuracy(7)?,
            left_natural: accuracy(8)?,
            builtin_left_natural: accuracy(9)?,
        });
    }
    Ok(rows)
}

/// The table: one row per (model, solver), sweeps and solve time against the first solver's
/// builtin (or its first model where builtin was not run).
pub fn markdown(summaries: &[(&str, Vec<SummaryRow>)]) -> String {
    let mut out = String::from(
        "| model | solver | total sweeps | vs first solver's builtin | solve time (ms) | vs first solver's builtin | capped steps | same states vs builtin (this solver) |\n|---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    let Some((_, first)) = summaries.first() else { return out };
    let Some(base) = first.iter().find(|r| r.model == "builtin").or(first.first()) else { return out };
    let mut models: Vec<&str> = Vec::new();
    for (_, rows) in summaries {
        for r in rows {
            if !models.contains(&r.model.as_str()) {
                models.push(&r.model);
            }
        }
    }
    for model in models {
        for (solver, rows) in summaries {
            let Some(r) = rows.iter().find(|r| r.model == model) else { continue };
            let same = if r.same_states.is_finite() { format!("{:.3}x", r.same_states) } else { "-".into() };
            out += &format!(
                "| {model} | {solver} | {} | {:.3}x | {:.1} | {:.3}x | {} | {same} |\n",
                r.total_sweeps,
                r.total_sweeps as f64 / base.total_sweeps.max(1) as f64,
                r.total_solve_ms,
                r.total_solve_ms / base.total_solve_ms.max(1e-9),
                r.cap_hits,
            );
        }
    }
    out
}

/// The budget table: one row per (model, budget), its accuracy after the budget and where that
/// sits on builtin's curve over the evaluated budgets (`worth`: the budget at which builtin is as
/// accurate, interpolated log-log; `<`/`>` outside the budgets evaluated).
pub fn budget_markdown(summaries: &[(u32, Vec<SummaryRow>)]) -> String {
    let mut out = String::from(
        "\"time at equal accuracy\": what a user buys, the model's critical path (warm start, inference included, and solve; median over the steps with contacts) over builtin's at the budget where builtin is as accurate (\"< r\": builtin is never as accurate over these budgets, r at the largest; \"-\": less accurate than builtin at the smallest).\n\n| model | budget | time at equal accuracy | RMS natural residual | worth (builtin sweeps) | critical path, median (us) | penetration max (m) | kinetic energy, late (J) | solve time (ms) | total sweeps |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let curve: Vec<(f64, f64)> = summaries
        .iter()
        .filter_map(|(k, rows)| rows.iter().find(|r| r.model == "builtin").map(|r| (*k as f64, r.natural_rms)))
        .collect();
    let time: Vec<(f64, f64)> = summaries
        .iter()
        .filter_map(|(k, rows)| rows.iter().find(|r| r.model == "builtin").map(|r| (*k as f64, r.median_critical_us)))
        .collect();
    let mut models: Vec<&str> = Vec::new();
    for (_, rows) in summaries {
        for r in rows {
            if !models.contains(&r.model.as_str()) {
                models.push(&r.model);
            }
        }
    }
    let num = msgs::curve::figure;
    for &model in &models {
        for (k, rows) in summaries {
            let Some(r) = rows.iter().find(|r| r.model == model) else { continue };
            let buys = msgs::curve::time_ratio(&curve, &time, r.natural_rms, r.median_critical_us);
            let critical =
                if r.median_critical_us.is_finite() { format!("{:.1}", r.median_critical_us) } else { "-".into() };
            out += &format!(
                "| {model} | {k} | {} | {} | {} | {critical} | {} | {} | {:.1} | {} |\n",
                msgs::curve::time_ratio_cell(buys),
                num(r.natural_rms),
                msgs::curve::worth(&curve, r.natural_rms),
                num(r.penetration_max),
                num(r.late_kinetic_energy),
                r.total_solve_ms,
                r.total_sweeps,
            );
        }
    }
    let split: Vec<(u32, &SummaryRow)> = models
        .iter()
        .flat_map(|&model| {
            summaries.iter().filter_map(move |(k, rows)| rows.iter().find(|r| r.model == model).map(|r| (*k, r)))
        })
        .filter(|(_, r)| r.left_rms.is_finite())
        .collect();
    if !split.is_empty() {
        out += "\nWhich part of builtin's warm-start error each model removes (`--error-split`): the share of builtin's smooth (pile-wide) and rough (local) error RMS the model's start does not have (negative: further from the exact solution), and the RMS error the budget's sweeps leave from the model's start and from builtin's on the same steps (the part slow for the solver); and the RMS natural residual those sweeps leave from each start (solver-independent, blind to which of a jammed pile's many solutions a start heads for: the same-states comparison at the budget).\n\n| model | budget | smooth removed | rough removed | left after the budget | builtin's left | natural residual left | builtin's natural residual left |\n|---|---:|---:|---:|---:|---:|---:|---:|\n";
        // Rounded before printing, so that a share just below zero reads 0%, not -0%.
        let percent = |share: f64| format!("{:.0}%", (100.0 * share).round() + 0.0);
        for (k, r) in split {
            out += &format!(
                "| {} | {k} | {} | {} | {} | {} | {} | {} |\n",
                r.model,
                percent(r.smooth_removed),
                percent(r.rough_removed),
                num(r.left_rms),
                num(r.builtin_left_rms),
                num(r.left_natural),
                num(r.builtin_left_natural),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const SUMMARY: &str = "model,total_sweeps,cap_hits,same_states_ratio_to_builtin,total_solve_ms\nbuiltin,1000,3,1,50.0\ngnn,990,2,0.99,55.0\n";

    #[test]
    fn summaries_read_and_tabulate_against_the_first_solvers_builtin() {
        let pgs = read_summary(SUMMARY).unwrap();
        let g = &pgs[1];
        assert_eq!(
            (g.model.as_str(), g.total_sweeps, g.total_solve_ms, g.cap_hits, g.same_states),
            ("gnn", 990, 55.0, 2, 0.99)
        );
        assert!(g.natural_rms.is_nan(), "a report without the accuracy columns reads as not measured");
        let nncg = read_summary(
            "model,total_sweeps,cap_hits,same_states_ratio_to_builtin,total_solve_ms\nbuiltin,400,0,1,20\n",
        )
        .unwrap();
        let table = markdown(&[("pgs", pgs), ("nncg:1.2/down", nncg)]);
        assert!(table.contains("| builtin | nncg:1.2/down | 400 | 0.400x | 20.0 | 0.400x | 0 | 1.000x |"), "{table}");
        assert!(table.contains("| gnn | pgs | 990 | 0.990x | 55.0 | 1.100x | 2 | 0.990x |"), "{table}");
    }

    #[test]
    fn the_budget_table_places_each_model_on_builtins_curve() {
        // Builtin's critical path is 10 us a sweep; gnn's is 10 us a sweep plus 5 us of inference.
        let at = |k: u32, builtin: f64, gnn: &str| {
            let text = format!(
                "model,total_sweeps,cap_hits,same_states_ratio_to_builtin,total_solve_ms,median_critical_us,mean_natural_rms,mean_penetration_max,late_kinetic_energy\nbuiltin,{},0,,5.0,{},{builtin},0.01,8.5\ngnn,{},0,,9.0,{},{gnn},0.02,\n",
                k * 100,
                k * 10,
                k * 100,
                k * 10 + 5,
            );
            (k, read_summary(&text).unwrap())
        };
        // builtin's error halves per doubling: gnn at 4 with 0.5 / sqrt(2) is worth sqrt(32) = 5.7 sweeps.
        let table = budget_markdown(&[at(4, 0.5, "0.35355339"), at(8, 0.25, "0.125"), at(16, 0.125, "0.3")]);
        assert!(
            table.contains("| builtin | 8 | 1.00x | 0.2500 | 8.0 | 80.0 | 0.0100 | 8.5000 | 5.0 | 800 |"),
            "{table}"
        );
        // 45 us against builtin's 40 + 0.5 * 40 = 60 us at 5.7 sweeps (linear in log k): 0.75x.
        assert!(table.contains("| gnn | 4 | 0.75x | 0.3536 | 5.7 | 45.0 | 0.0200 | - | 9.0 | 400 |"), "{table}");
        // As accurate at 8 as builtin at 16, in 85 us against builtin's 160: what the user buys.
        assert!(table.contains("| gnn | 8 | 0.53x | 0.1250 | 16.0 | 85.0 |"), "{table}");
        assert!(table.contains("| gnn | 16 | 2.37x | 0.3000 | 6.7 |"), "{table}");
        // Better than builtin at the largest budget: at most its time ratio there.
        let better = budget_markdown(&[at(4, 0.5, "0.2"), at(8, 0.25, "0.3"), at(16, 0.125, "0.01")]);
        assert!(better.contains("| gnn | 16 | < 1.03x | 0.0100 | > 16 |"), "{better}");
        // A report from before the accuracy columns reads as not measured.
        let old = read_summary(SUMMARY).unwrap();
        assert!(
            old[0].natural_rms.is_nan() && old[0].late_kinetic_energy.is_nan() && old[0].median_critical_us.is_nan()
        );
        assert!(!table.contains("Which part"), "no split measured: no split table\n{table}");
    }

    #[test]
    fn the_budget_table_says_which_part_of_the_error_a_model_removes_where_measured() {
        let text = "model,total_sweeps,cap_hits,same_states_ratio_to_builtin,total_solve_ms,mean_natural_rms,split_smooth_removed,split_rough_removed,split_left_rms,split_builtin_left_rms,split_left_natural,split_builtin_left_natural\nbuiltin,800,0,,5.0,0.25,-0.001,0,0.6,0.6,0.011,0.011\nunet-delta,800,0,,90.0,0.2,-0.15,-0.3,0.49,0.63,0.0101,0.0108\nnone,800,0,,4.0,0.5,,,,,,\n";
        let rows = read_summary(text).unwrap();
        assert!(rows[2].left_rms.is_nan() && rows[2].smooth_removed.is_nan(), "empty cells: not measured");
        let table = budget_markdown(&[(8, rows)]);
        assert!(table.contains("| unet-delta | 8 | -15% | -30% | 0.4900 | 0.6300 | 0.0101 | 0.0108 |"), "{table}");
        assert!(table.contains("| builtin | 8 | 0% | 0% | 0.6000 | 0.6000 | 0.0110 | 0.0110 |"), "{table}");
        let (_, split) = table.split_once("Which part").expect("a split table");
        assert!(!split.lines().any(|l| l.starts_with("| none |")), "not measured: no split row\n{table}");
        assert!(!table.contains("NaN"), "{table}");
        assert_eq!(table.lines().filter(|l| l.starts_with("| none |")).count(), 1, "only the accuracy row: {table}");
    }

    #[test]
    fn a_broken_summary_says_where() {
        assert!(matches!(read_summary(""), Err(SummaryError::Empty)));
        let e = read_summary("model,total_sweeps\nbuiltin,1\n").unwrap_err();
        assert_eq!(e.to_string(), "column `total_solve_ms` is missing");
        let bad = SUMMARY.replace("990", "lots");
        assert_eq!(
            read_summary(&bad).unwrap_err().to_string(),
            "line 3: column `total_sweeps`: `lots` is not a number"
        );
        let ragged = SUMMARY.replace("gnn,990,", "gnn,");
        assert!(read_summary(&ragged).unwrap_err().to_string().starts_with("line 3: 4 fields"));
    }
}
