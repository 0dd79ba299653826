//! What picks a member of the solver family ([`SolverSetting`]: iteration and row order) and
//! when a solve stops ([`StopRule`]), with their command-line spellings.

use std::fmt;
use std::str::FromStr;

/// Relaxation lies strictly between 0 and this: outside, projected SOR does not converge.
pub const RELAXATION_LIMIT: f32 = 2.0;

/// Whether `omega` is a relaxation projected SOR converges with: in (0, [`RELAXATION_LIMIT`]).
pub fn valid_relaxation(omega: f32) -> bool {
    omega.is_finite() && omega > 0.0 && omega < RELAXATION_LIMIT
}

/// A momentum step after each sweep.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Momentum {
    /// None: plain (projected) Gauss-Seidel or SOR sweeps.
    #[default]
    None,
    /// Nonsmooth nonlinear conjugate gradient: restart when `beta` exceeds `restart` (the paper
    /// and Bullet: 1; 0 restarts every sweep, which is PGS bit for bit).
    Nncg { restart: f32 },
}

/// How a step's problem is solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Method {
    /// Sweeps over the rows: the projected Gauss-Seidel family.
    #[default]
    Sweeps,
    /// Newton's method on the problem's proximal augmented Lagrangian in body velocities, a
    /// sparse Cholesky per iteration ([`super::newton`]).
    Newton,
    /// The primal-dual interior-point method on the step's QP, a sparse Cholesky per
    /// iteration ([`super::newton`]), in one of its variants.
    InteriorPoint(InteriorVariant),
    /// MPRGP, conjugate gradients on the step's box-constrained QP ([`super::krylov`]).
    Mprgp,
    /// The fastest measured at the problem's size: the interior-point method from
    /// [`AUTO_NEWTON_FROM`] dynamic bodies on (if ever), the sweeps below.
    Auto,
}

/// The interior point's variant: `ipm` (neither), `ipm:nd`, `ipm:warm` or `ipm:nd+warm`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct InteriorVariant {
    /// `nd`: the system ordered by nested dissection of the contact graph from the bodies'
    /// positions, its symbolic analysis kept while the body pairs stay among the kept pattern's
    /// ([`super::newton::Ordering::Dissection`]); else faer's minimum degree, the analysis kept
    /// while the pairs are the same.
    pub dissection: bool,
    /// `warm`: the warm start centred in the interior ([`super::newton::NewtonParams::centred_start`])
    /// rather than pushed a fixed way inside.
    pub centred_start: bool,
}

impl InteriorVariant {
    /// Every variant with its spelling.
    pub const SPELLINGS: [(InteriorVariant, &'static str); 4] = [
        (InteriorVariant { dissection: false, centred_start: false }, "ipm"),
        (InteriorVariant { dissection: true, centred_start: false }, "ipm:nd"),
        (InteriorVariant { dissection: false, centred_start: true }, "ipm:warm"),
        (InteriorVariant { dissection: true, centred_start: true }, "ipm:nd+warm"),
    ];

    pub fn name(self) -> &'static str {
        Self::SPELLINGS.iter().find(|(v, _)| *v == self).map(|(_, s)| *s).expect("every variant is spelled")
    }

    /// Its code in a recorded problem's header (`ipm` is 3, as before the variants).
    pub fn code(self) -> u32 {
        match (self.dissection, self.centred_start) {
            (false, false) => 3,
            (true, false) => 5,
            (false, true) => 6,
            (true, true) => 7,
        }
    }

    pub fn of_code(code: u32) -> Option<InteriorVariant> {
        Self::SPELLINGS.iter().map(|(v, _)| *v).find(|v| v.code() == code)
    }
}

/// The problem size (dynamic bodies) from which `auto` solves with the interior-point method:
/// none so far. To the natural residual 1e-4 on the same states NNCG (`nncg:1.2/down`) is faster
/// at every size measured: 5.0x the interior point's speed at 1,000 bodies (per-step friction,
/// 0.20x PGS's time against 0.99x), 6x at 400, 8x at 100 (docs/solvers.md). The interior point's
/// iterations barely grow with the pile, its time per iteration does; a size where it wins would
/// be set here once measured.
pub const AUTO_NEWTON_FROM: Option<usize> = None;

/// Which law bounds the friction impulse of a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrictionModel {
    /// Box2D's law: `|tangent| <= mu * normal` of the step's own normal impulse (the
    /// complementarity problem is not convex; friction and normal load are coupled).
    #[default]
    Box,
    /// The bound frozen per step at `mu` times the contact's normal impulse of the previous
    /// step (a contact on its first step takes the Box2D law): each step's problem is a convex
    /// quadratic program with box constraints.
    PerStep,
}

impl Keyword for FrictionModel {
    const WHAT: &'static str = "friction model";
    const KEYWORDS: &'static [(Self, &'static str)] =
        &[(FrictionModel::Box, "box"), (FrictionModel::PerStep, "per-step")];
}

impl FrictionModel {
    pub fn name(self) -> &'static str {
        self.keyword()
    }
}

impl fmt::Display for FrictionModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for FrictionModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::from_keyword(s)
    }
}

/// The order the rows are visited in within a sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RowOrder {
    /// The contacts' order: sorted by key (body pair, feature), as recorded.
    #[default]
    Recorded,
    /// By contact height, top first, every step (ties in the recorded order): a pile's weight
    /// reaches the floor within one sweep.
    Down,
    /// Coloured (Box2D v3's graph colouring): the rows split greedily, top-down, into colours no
    /// two rows of which share a moving body, visited colour after colour, each colour's rows
    /// updated on all threads at once ([`super::colour`]). The same bits on any thread count.
    Colour,
}

/// A coarse correction between the sweeps ([`super::coarse`]): every `every` sweeps, the step's
/// problem restricted to its active set is solved exactly within uniform stress fields over
/// square cells of side `cell` metres, and the impulses move by that solution if it lowers the
/// problem's energy. Spelled `/coarse`, `/coarse:S` or `/coarse:S:K` after the method (and order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarseCorrection {
    /// Side of a cell, metres.
    pub cell: f32,
    /// Sweeps between corrections (the first after this many).
    pub every: u32,
}

impl CoarseCorrection {
    /// `/coarse`: cells of 8 m, every 64 sweeps: the least time lost of the spellings tried on
    /// the validation seeds (docs/solvers.md); no spelling saved time against plain NNCG.
    pub const DEFAULT: CoarseCorrection = CoarseCorrection { cell: 8.0, every: 64 };
    /// The range a cell's side may take, metres.
    pub const CELLS: std::ops::RangeInclusive<f32> = 0.25..=1000.0;

    pub fn is_valid(&self) -> bool {
        Self::CELLS.contains(&self.cell) && self.every >= 1
    }
}

impl fmt::Display for CoarseCorrection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let default = Self::DEFAULT;
        if *self == default {
            f.write_str("coarse")
        } else if self.every == default.every {
            write!(f, "coarse:{}", self.cell)
        } else {
            write!(f, "coarse:{}:{}", self.cell, self.every)
        }
    }
}

impl FromStr for CoarseCorrection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let mut parts = s.split(':');
        if parts.next() != Some("coarse") {
            return Err(format!("unknown correction `{s}`"));
        }
        let mut correction = Self::DEFAULT;
        if let Some(cell) = parts.next() {
            correction.cell = cell.parse().map_err(|e| format!("coarse cell `{cell}`: {e}"))?;
        }
        if let Some(every) = parts.next() {
            correction.every = every.parse().map_err(|e| format!("coarse every `{every}`: {e}"))?;
        }
        if parts.next().is_some() {
            return Err(format!("`{s}`: at most a cell and a sweep count (coarse:S:K)"));
        }
        if !correction.is_valid() {
            return Err(format!(
                "`{s}`: a cell in [{}, {}] m and at least 1 sweep between corrections",
                Self::CELLS.start(),
                Self::CELLS.end()
            ));
        }
        Ok(correction)
    }
}

/// When a solve has converged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StopRule {
    /// The largest absolute impulse change of a sweep is at most the tolerance (the thesis's
    /// rule). It depends on the iteration: an over-relaxed sweep moves further, a momentum step
    /// is not a sweep.
    #[default]
    Change,
    /// The natural residual ([`super::NaturalResidual`], the max over rows) is at most the
    /// tolerance: the same accuracy whatever the solver.
    Natural,
    /// The natural residual is at most the tolerance times the warm start's RMS impulse (per
    /// row, the length of its normal and tangent parts): the same relative accuracy in a deep
    /// pile, whose bottom loads grow with its depth, as in a shallow one. A start that is all
    /// zero keeps the absolute tolerance. A simulation scales by builtin's start (the previous
    /// step's impulses) whatever the model's, so that every model is held to the same accuracy.
    Relative,
}

/// An enum the command line spells by keyword: every value with its keyword.
trait Keyword: Copy + PartialEq + 'static {
    /// What the keywords name, for errors (`stopping rule`).
    const WHAT: &'static str;
    const KEYWORDS: &'static [(Self, &'static str)];

    fn keyword(self) -> &'static str {
        Self::KEYWORDS.iter().find(|(v, _)| *v == self).map(|(_, k)| *k).expect("every value has a keyword")
    }

    fn from_keyword(s: &str) -> Result<Self, String> {
        Self::KEYWORDS.iter().find(|(_, k)| *k == s).map(|(v, _)| *v).ok_or_else(|| {
            let all: Vec<&str> = Self::KEYWORDS.iter().map(|(_, k)| *k).collect();
            format!("unknown {} `{s}` (expected one of: {})", Self::WHAT, all.join(", "))
        })
    }
}

impl Keyword for StopRule {
    const WHAT: &'static str = "stopping rule";
    const KEYWORDS: &'static [(Self, &'static str)] =
        &[(StopRule::Change, "change"), (StopRule::Natural, "natural"), (StopRule::Relative, "relative")];
}

impl Keyword for RowOrder {
    const WHAT: &'static str = "row order";
    const KEYWORDS: &'static [(Self, &'static str)] =
        &[(RowOrder::Recorded, "recorded"), (RowOrder::Down, "down"), (RowOrder::Colour, "colour")];
}

impl StopRule {
    /// The rule `dc-sim` uses unless told otherwise: the same accuracy for every solver.
    pub const RECOMMENDED: StopRule = StopRule::Natural;

    pub fn name(self) -> &'static str {
        self.keyword()
    }
}

impl RowOrder {
    pub fn name(self) -> &'static str {
        self.keyword()
    }
}

impl fmt::Display for StopRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for StopRule {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::from_keyword(s)
    }
}

impl FromStr for RowOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::from_keyword(s)
    }
}

/// A member of the solver family: the iteration (relaxation, momentum) and the row order.
/// Spelled `pgs`, `sor:W` (W in (0, 2)), `nncg` or `nncg:R` (restart threshold R >= 0), with
/// `/down` for the top-down row order (`sor:1.4/down`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSetting {
    /// Sweeps, a second-order method, or by size; a second-order method falls back to the
    /// sweeps below if it fails and hands them its impulses if it stops short of the tolerance.
    pub method: Method,
    pub relaxation: f32,
    pub momentum: Momentum,
    pub order: RowOrder,
    /// A coarse correction between the sweeps (one-thread orders only), or none.
    pub coarse: Option<CoarseCorrection>,
}

impl Default for SolverSetting {
    fn default() -> Self {
        SolverSetting::PGS
    }
}

impl SolverSetting {
    /// The thesis's solver: projected Gauss-Seidel in the recorded order.
    pub const PGS: SolverSetting = SolverSetting {
        method: Method::Sweeps,
        relaxation: 1.0,
        momentum: Momentum::None,
        order: RowOrder::Recorded,
        coarse: None,
    };

    /// The solver `dc-sim` uses unless told otherwise: NNCG restarting above 1.2, rows top-down
    /// (0.34x PGS's sweeps and 0.36x its time to the same natural residual on the evaluation
    /// seeds; chosen on validation seeds, docs/research/solver-study.md).
    pub const RECOMMENDED: SolverSetting = SolverSetting {
        method: Method::Sweeps,
        relaxation: 1.0,
        momentum: Momentum::Nncg { restart: 1.2 },
        order: RowOrder::Down,
        coarse: None,
    };

    /// Newton ([`Method::Newton`]), the recommended sweeps behind it.
    pub const NEWTON: SolverSetting = SolverSetting { method: Method::Newton, ..SolverSetting::RECOMMENDED };

    /// The interior-point method ([`Method::InteriorPoint`]), the recommended sweeps behind it.
    pub const INTERIOR_POINT: SolverSetting = SolverSetting {
        method: Method::InteriorPoint(InteriorVariant { dissection: false, centred_start: false }),
        ..SolverSetting::RECOMMENDED
    };

    /// The interior-point method from [`AUTO_NEWTON_FROM`] dynamic bodies (none measured yet),
    /// the recommended sweeps below.
    pub const AUTO: SolverSetting = SolverSetting { method: Method::Auto, ..SolverSetting::RECOMMENDED };

    pub const MPRGP: SolverSetting = SolverSetting { method: Method::Mprgp, ..SolverSetting::RECOMMENDED };

    /// What `--solver` accepts, in words.
    pub const SPELLING: &'static str = "ipm (interior point), ipm:nd, ipm:warm, ipm:nd+warm (ordered by nested dissection, from the centred warm start, both), newton (proximal Newton), mprgp (conjugate gradients on the QP), auto (the fastest measured at the size: nncg:1.2/down at every size so far), pgs, sor:W (W in (0, 2)), nncg or nncg:R (restart above R >= 0; nncg = nncg:1), each optionally with /down (rows top-down), /colour (rows coloured, swept on --threads threads) or /recorded, then optionally /coarse, /coarse:S or /coarse:S:K (a coarse correction over cells of S m every K sweeps; one-thread orders)";

    /// The sweeps of this setting (what a second-order method falls back to and finishes with;
    /// itself for the sweeps).
    pub fn sweeps(self) -> SolverSetting {
        SolverSetting { method: Method::Sweeps, ..self }
    }

    /// Whether the setting is one the solver accepts (a relaxation in (0, 2), a finite restart
    /// threshold >= 0).
    pub fn is_valid(&self) -> bool {
        valid_relaxation(self.relaxation)
            && self.coarse.is_none_or(|c| c.is_valid() && self.order != RowOrder::Colour)
            && match self.momentum {
                Momentum::None => true,
                Momentum::Nncg { restart } => restart.is_finite() && restart >= 0.0,
            }
    }
}

impl fmt::Display for SolverSetting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.method {
            Method::Newton => return f.write_str("newton"),
            Method::InteriorPoint(variant) => return f.write_str(variant.name()),
            Method::Auto => return f.write_str("auto"),
            Method::Mprgp => return f.write_str("mprgp"),
            Method::Sweeps => {}
        }
        match (self.momentum, self.relaxation) {
            (Momentum::None, 1.0) => write!(f, "pgs")?,
            (Momentum::None, w) => write!(f, "sor:{w}")?,
            (Momentum::Nncg { restart }, w) => {
                if restart == 1.0 {
                    write!(f, "nncg")?
                } else {
                    write!(f, "nncg:{restart}")?
                }
                if w != 1.0 {
                    write!(f, "+sor:{w}")?
                }
            }
        }
        if self.order != RowOrder::Recorded {
            write!(f, "/{}", self.order.name())?
        }
        if let Some(coarse) = self.coarse {
            write!(f, "/{coarse}")?
        }
        Ok(())
    }
}

impl FromStr for SolverSetting {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |why: String| format!("solver `{s}`: {why} (expected {})", Self::SPELLING);
        match s {
            "newton" => return Ok(SolverSetting::NEWTON),
            "auto" => return Ok(SolverSetting::AUTO),
            "mprgp" => return Ok(SolverSetting::MPRGP),
            _ => {}
        }
        if let Some((variant, _)) = InteriorVariant::SPELLINGS.iter().find(|(_, name)| *name == s) {
            return Ok(SolverSetting { method: Method::InteriorPoint(*variant), ..SolverSetting::RECOMMENDED });
        }
        let mut parts = s.split('/');
        let method = parts.next().unwrap_or_default();
        let mut whole =
            ["newton", "auto", "mprgp"].into_iter().chain(InteriorVariant::SPELLINGS.iter().map(|(_, n)| *n));
        if whole.any(|m| m == method) {
            return Err(bad(format!("`{method}` is not a sweep method: it takes no /order or /coarse")));
        }
        let (mut order, mut coarse) = (None, None);
        for part in parts {
            if part.starts_with("coarse") {
                if coarse.replace(part.parse::<CoarseCorrection>().map_err(bad)?).is_some() {
                    return Err(bad("two coarse corrections".to_string()));
                }
            } else if order.replace(part.parse::<RowOrder>().map_err(bad)?).is_some() || coarse.is_some() {
                return Err(bad(format!("the row order `{part}` comes once, before /coarse")));
            }
        }
        let order = order.unwrap_or(RowOrder::Recorded);
        if coarse.is_some() && order == RowOrder::Colour {
            return Err(bad(
                "the coarse correction runs between one-thread sweeps (recorded or down order), not /colour"
                    .to_string(),
            ));
        }
        let number = |v: &str| v.parse::<f32>().map_err(|e| bad(format!("`{v}`: {e}")));
        // `nncg+sor:W`: the momentum over relaxed sweeps (the scratch study saw it diverge or
        // stall; kept spellable so that it can be measured).
        let (momentum, relaxation_part) = match method.split_once('+') {
            Some((m, r)) => (m, Some(r)),
            None if method.starts_with("nncg") => (method, None),
            None => ("", Some(method)),
        };
        let momentum = match momentum {
            "" => Momentum::None,
            "nncg" => Momentum::Nncg { restart: 1.0 },
            m => match m.strip_prefix("nncg:") {
                Some(r) => Momentum::Nncg { restart: number(r)? },
                None => return Err(bad(format!("unknown method `{m}`"))),
            },
        };
        let relaxation = match relaxation_part {
            None | Some("pgs") => 1.0,
            Some(r) => match r.strip_prefix("sor:") {
                Some(w) => number(w)?,
                None => return Err(bad(format!("unknown method `{r}`"))),
            },
        };
        let setting = SolverSetting { method: Method::Sweeps, relaxation, momentum, order, coarse };
        if !setting.is_valid() {
            return Err(bad("out of range".to_string()));
        }
        Ok(setting)
    }
}

/// A comma-separated list of solver settings (`pgs,sor:1.4/down,nncg`), each named once.
pub fn parse_settings(list: &str) -> Result<Vec<SolverSetting>, String> {
    let mut settings: Vec<SolverSetting> = Vec::new();
    for part in list.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let s: SolverSetting = part.parse()?;
        if settings.contains(&s) {
            return Err(format!("solver `{part}` is asked for twice"));
        }
        settings.push(s);
    }
    if settings.is_empty() {
        return Err(format!("no solver in `{list}`"));
    }
    Ok(settings)
}

/// One spelling of every kind of setting, as the settings print themselves (the tests' list).
#[cfg(test)]
pub(crate) const SPELLED: [&str; 21] = [
    "newton",
    "ipm",
    "ipm:nd",
    "ipm:warm",
    "ipm:nd+warm",
    "mprgp",
    "auto",
    "pgs",
    "sor:1.4",
    "nncg",
    "nncg:0",
    "nncg:2.5",
    "pgs/down",
    "sor:1.2/down",
    "nncg/down",
    "nncg:1.2/colour",
    "pgs/colour",
    "nncg+sor:1.3",
    "nncg:1.2/down/coarse",
    "pgs/coarse:2",
    "nncg/down/coarse:3:8",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_read_back_what_they_print() {
        for s in SPELLED {
            let setting: SolverSetting = s.parse().unwrap();
            assert_eq!(setting.to_string(), s);
            assert_eq!(setting.to_string().parse::<SolverSetting>().unwrap(), setting);
        }
        assert_eq!("sor:1".parse::<SolverSetting>().unwrap(), SolverSetting::PGS);
        assert_eq!("pgs/recorded".parse::<SolverSetting>().unwrap(), SolverSetting::PGS);
    }

    #[test]
    fn bad_settings_say_what_is_wrong() {
        for (s, says) in [
            ("sor:2", "out of range"),
            ("sor:0", "out of range"),
            ("sor:nan", "out of range"),
            ("nncg:-1", "out of range"),
            ("sor:x", "`x`"),
            ("jacobi", "unknown method `jacobi`"),
            ("pgs/up", "unknown row order `up`"),
            ("nncg/colour/coarse", "not /colour"),
            ("nncg/down/coarse:0.1", "a cell in [0.25, 1000]"),
            ("nncg/down/coarse:2:0", "at least 1 sweep"),
            ("nncg/down/coarse:x", "coarse cell `x`"),
            ("nncg/down/coarse:2:8:1", "at most a cell"),
            ("nncg/coarse/down", "before /coarse"),
            ("nncg/coarse/coarse", "two coarse"),
            ("ipm/coarse", "`ipm` is not a sweep method"),
            ("mprgp/down", "`mprgp` is not a sweep method"),
        ] {
            let e = s.parse::<SolverSetting>().unwrap_err();
            assert!(e.contains(s) && e.contains(says) && e.contains("expected"), "{s}: {e}");
        }
        assert!(parse_settings("pgs,sor:1.4,pgs").unwrap_err().contains("twice"));
        assert!(parse_settings(" , ").unwrap_err().contains("no solver"));
        assert!("natural".parse::<StopRule>().is_ok() && "tight".parse::<StopRule>().is_err());
        assert_eq!("per-step".parse::<FrictionModel>(), Ok(FrictionModel::PerStep));
        assert!("coulomb".parse::<FrictionModel>().unwrap_err().contains("box, per-step"));
    }
}
