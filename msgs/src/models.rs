//! The warm-start models a simulator can run, by name: the one list the simulator, the launcher's
//! evaluation, the metrics report and the nodes that serve grids agree on.

use crate::topics;

/// The three rooms of the models: what a user runs, what the evaluation measures with, what
/// research tried.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ModelGroup {
    /// What a simulator user runs: computed from what a simulator has.
    Product,
    /// Instruments of the evaluation: built from the step's exact solution (the oracle) or
    /// deliberately poor; they bound and map what a model can gain.
    Reference,
    /// Experiments on where the sweeps are (history extrapolation, Galerkin and CG corrections).
    Probe,
}

impl ModelGroup {
    /// Every group, in the order help texts list them.
    pub const ALL: [ModelGroup; 3] = [ModelGroup::Product, ModelGroup::Reference, ModelGroup::Probe];

    /// The group's heading in help texts.
    pub fn title(self) -> &'static str {
        match self {
            ModelGroup::Product => "product (what a simulator runs)",
            ModelGroup::Reference => "references (evaluation instruments: the oracle and deliberately poor starts)",
            ModelGroup::Probe => "probes (research experiments)",
        }
    }
}

/// One warm-start model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelInfo {
    pub name: &'static str,
    /// Which room the model belongs to.
    pub group: ModelGroup,
    /// The topic another node answers this model's warm starts on: a grid topic for the
    /// grid-based models, `warm/gnn` for `gnn-node`; None: computed in the simulator.
    pub served_on: Option<&'static str>,
    /// The model's one numeric parameter, written `name:value` (`blend:0.75`), if it has one.
    pub param: Option<Param>,
    pub about: &'static str,
}

/// A model's numeric parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Param {
    /// What it is, for help texts.
    pub what: &'static str,
    pub default: f32,
    pub min: f32,
    pub max: f32,
}

impl ModelInfo {
    /// The grid topic of a grid-based model.
    pub fn grid_topic(&self) -> Option<&'static str> {
        self.served_on.filter(|t| topics::FrameKind::of_topic(t) == Some(topics::FrameKind::Grid))
    }

    pub fn is_grid_based(&self) -> bool {
        self.grid_topic().is_some()
    }
}

/// The topic a node serves model `spec` on (`unet` and `unet-delta`: `grid/unet`), None for a
/// model computed in the simulator or an unknown name.
pub fn served_on(spec: &str) -> Option<&'static str> {
    parse(spec).ok().and_then(|(m, _)| m.served_on)
}

const fn plain(name: &'static str, group: ModelGroup, about: &'static str) -> ModelInfo {
    ModelInfo { name, group, served_on: None, param: None, about }
}

/// A model computed in the simulator with one numeric parameter.
const fn with_param(name: &'static str, group: ModelGroup, param: Param, about: &'static str) -> ModelInfo {
    ModelInfo { name, group, served_on: None, param: Some(param), about }
}

/// A model whose warm starts another node answers on `topic`.
const fn served(name: &'static str, group: ModelGroup, topic: &'static str, about: &'static str) -> ModelInfo {
    ModelInfo { name, group, served_on: Some(topic), param: None, about }
}

/// Every model: the thesis's table, then the oracle ablations and baselines of the accuracy ->
/// sweeps curve, then the grid-based models.
pub const MODELS: &[ModelInfo] = &[
    plain("none", ModelGroup::Product, "cold start: zero impulses"),
    plain("builtin", ModelGroup::Product, "the previous step's impulse of each persisting contact, 0 on new ones"),
    plain("copy", ModelGroup::Reference, "oracle: the step's problem solved from builtin's warm start to the oracle tolerance"),
    plain("copy0", ModelGroup::Reference, "oracle rounded to 0 decimals"),
    plain("copy2", ModelGroup::Reference, "oracle rounded to 2 decimals"),
    plain("bad", ModelGroup::Reference, "a deliberately wrong warm start (50 everywhere)"),
    plain("random", ModelGroup::Reference, "random impulses of the solution's scale"),
    with_param(
        "extrapolate",
        ModelGroup::Probe,
        Param { what: "beta: l1 + beta (l1 - l2)", default: 1.0, min: 0.0, max: 2.0 },
        "damped extrapolation of the last two steps (beta 1: linear)",
    ),
    with_param(
        "continue",
        ModelGroup::Probe,
        Param { what: "G: builtin + G x the last solve's remaining distance", default: 1.0, min: 0.0, max: 4.0 },
        "builtin plus G times where the previous solve was still going: its last sweep's change times rate / (1 - rate)",
    ),
    with_param(
        "subspace",
        ModelGroup::Probe,
        Param { what: "K: the previous solve's last K sweeps span the correction", default: 2.0, min: 1.0, max: 4.0 },
        "builtin corrected, by the step's own K x K Galerkin system, along the previous solve's last K sweep changes (its slowest modes)",
    ),
    with_param(
        "coarse",
        ModelGroup::Probe,
        Param { what: "S: side of a cell in metres", default: 2.0, min: 0.25, max: 1000.0 },
        "builtin plus a coarse-grid correction: the step's own problem solved (Galerkin) within piecewise-uniform stress fields over cells of side S",
    ),
    with_param(
        "cg",
        ModelGroup::Probe,
        Param { what: "K: conjugate-gradient iterations (each about a sweep's work)", default: 50.0, min: 0.0, max: 10000.0 },
        "builtin plus K Jacobi-preconditioned CG iterations on the step's own linear problem on builtin's active set (with the solver's compliance; rigid problems regularised by 1e-4 W_ii)",
    ),
    plain("builtin-reappear", ModelGroup::Probe, "builtin, and a contact new this step that existed two steps ago gets that impulse"),
    plain("copy-persisting", ModelGroup::Reference, "oracle on persisting contacts, 0 on new ones"),
    plain("copy-new", ModelGroup::Reference, "builtin on persisting contacts, the oracle on new ones"),
    plain("copy-previous", ModelGroup::Reference, "the previous step's oracle on persisting contacts, 0 on new: builtin if every solve were finished"),
    with_param(
        "blend",
        ModelGroup::Reference,
        Param { what: "F: builtin + F (oracle - builtin)", default: 0.5, min: 0.0, max: 1.0 },
        "a fraction F of builtin's error removed",
    ),
    with_param(
        "noise",
        ModelGroup::Reference,
        Param { what: "S: noise of S x builtin's RMS error", default: 1.0, min: 0.0, max: 100.0 },
        "the oracle plus Gaussian noise of S times builtin's RMS error (per step)",
    ),
    plain("smooth-error", ModelGroup::Reference, "the oracle plus the smooth part of builtin's error (averaged over the contact graph)"),
    plain("rough-error", ModelGroup::Reference, "the oracle plus the rest of builtin's error (its local, high-frequency part)"),
    plain("gnn", ModelGroup::Product, "the contact-graph network's correction to builtin (in the simulator, `--gnn-model FILE`)"),
    with_param(
        "gnn-every",
        ModelGroup::Product,
        Param { what: "N: the network runs every N-th step", default: 4.0, min: 1.0, max: 1000.0 },
        "the contact-graph network every N-th step, its correction to builtin carried on the persisting contacts in between: builtin plus the correction of the last step the network ran (`--gnn-model FILE`)",
    ),
    with_param(
        "gnn-subspace",
        ModelGroup::Probe,
        Param { what: "K: the previous solve's last K sweeps beside the network's direction", default: 2.0, min: 0.0, max: 4.0 },
        "the network's correction as a direction only: builtin plus the amplitudes of it and the previous solve's last K sweeps that the step's own Galerkin system picks (`--gnn-model FILE`)",
    ),
    served("gnn-node", ModelGroup::Product, topics::WARM_GNN.name, "the contact-graph network served over the bus by a `dc-gnn` node, builtin when late or down"),
    served("gnn-pipelined", ModelGroup::Product, topics::WARM_GNN.name, "the contact-graph network served by a `dc-gnn` node one step ahead, off the critical path: step t's solved problem carried one step on goes out once solved, the prediction is matched to step t+1's contacts by key (builtin on new ones); builtin when late or down"),
    plain("copy-grid", ModelGroup::Reference, "oracle through the value-preserving grid transfer and back"),
    plain("copy-grid-sph", ModelGroup::Reference, "oracle through the thesis's grid transfer and back"),
    served("grid", ModelGroup::Product, topics::GRID_CONTACTS.name, "the previous step's impulses through the SPH node's grid"),
    served("unet", ModelGroup::Product, topics::GRID_UNET.name, "the U-Net's predicted impulse grid"),
    served("unet-delta", ModelGroup::Product, topics::GRID_UNET.name, "builtin plus the U-Net's predicted change on persisting contacts, its value on new ones"),
    served(EXTERNAL, ModelGroup::Product, topics::WARM_EXTERNAL.name, "your own model, `external:NAME`: a process of the graph (any language; `dc eval --serve CMD`) answers each step's problem on warm/external; its row is named NAME; builtin when late or down (docs/external.md)"),
];

/// The model a user's own process serves, written `external:NAME`.
pub const EXTERNAL: &str = "external";

/// The version of the external-model contract (docs/external.md): the topics `problem/bodies`,
/// `problem/contacts`, `control` to the server and `warm/external` back, their frames at
/// [`crate::WIRE_VERSION`], the reply's keys in the problem's order, the deadline and fallback
/// rules. A change a server would notice is a new version.
pub const EXTERNAL_CONTRACT_VERSION: u32 = 1;

/// The user's name of an external model (`external:py` -> `py`), None for any other spec.
pub fn external_name(spec: &str) -> Option<&str> {
    spec.strip_prefix(EXTERNAL).and_then(|rest| rest.strip_prefix(':'))
}

/// Why `name` cannot name an external model: it names its report row, its statistics (16
/// bytes) and its node in the graph, so it is 1 to 16 of `a-z 0-9 -`, starting with a letter,
/// and not one of the built-in models' names.
fn external_name_problem(name: &str) -> Option<String> {
    let shape = !name.is_empty()
        && name.len() <= 16
        && name.starts_with(|c: char| c.is_ascii_lowercase())
        && name.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-');
    if !shape {
        return Some(format!(
            "`{EXTERNAL}:{name}`: the name must be 1 to 16 of a-z, 0-9 and `-`, starting with a letter"
        ));
    }
    model(name).map(|_| format!("`{EXTERNAL}:{name}`: `{name}` is a built-in model's name; name yours otherwise"))
}

/// The name a model's statistics and report row carry: the user's for `external:NAME`, else the
/// canonical `name[:param]`.
pub fn canonical_name(spec: &str) -> Result<String, String> {
    let (info, param) = parse(spec)?;
    Ok(match external_name(spec) {
        Some(name) => name.to_string(),
        None => spec_name(info, param),
    })
}

/// The model of a name, without a parameter (`blend`, not `blend:0.5`).
pub fn model(name: &str) -> Option<&'static ModelInfo> {
    MODELS.iter().find(|m| m.name == name)
}

/// Parses `name` or `name:value` into the model and its parameter (the default when omitted).
pub fn parse(spec: &str) -> Result<(&'static ModelInfo, Option<f32>), String> {
    if let Some(name) = external_name(spec) {
        return match external_name_problem(name) {
            Some(why) => Err(why),
            None => Ok((model(EXTERNAL).expect("in the table"), None)),
        };
    }
    if spec == EXTERNAL {
        return Err(format!("`{EXTERNAL}` needs a name, `{EXTERNAL}:NAME`: the name its report row carries"));
    }
    let (name, value) = match spec.split_once(':') {
        Some((n, v)) => (n, Some(v)),
        None => (spec, None),
    };
    let info = model(name).ok_or_else(|| format!("unknown warm-start model `{name}` (known: {})", names_list()))?;
    let param = match (info.param, value) {
        (None, None) => None,
        (None, Some(_)) => return Err(format!("model `{name}` takes no parameter (`{spec}`)")),
        (Some(p), None) => Some(p.default),
        (Some(p), Some(v)) => match v.trim().parse::<f32>() {
            Ok(x) if x.is_finite() && (p.min..=p.max).contains(&x) => Some(x),
            _ => return Err(format!("`{spec}`: {} must be a number in [{}, {}]", p.what, p.min, p.max)),
        },
    };
    // The name the statistics carry is the canonical one (`extrapolate:.125` is
    // `extrapolate:0.125`): it must fit, or two models would share a truncated name.
    let canonical = spec_name(info, param);
    if canonical.len() > 16 {
        return Err(format!(
            "`{spec}` is named `{canonical}`, longer than 16 bytes, the statistics' name field (write fewer digits)"
        ));
    }
    Ok((info, param))
}

/// The canonical name of a model with its parameter (`blend:0.5`; the default included).
pub fn spec_name(info: &ModelInfo, param: Option<f32>) -> String {
    match param {
        Some(v) => format!("{}:{v}", info.name),
        None => info.name.to_string(),
    }
}

/// The models by group, one line per group (`product: none, builtin, ...`), for help texts.
pub fn groups_help() -> String {
    ModelGroup::ALL
        .iter()
        .map(|g| {
            let names: Vec<&str> = MODELS.iter().filter(|m| m.group == *g).map(|m| m.name).collect();
            format!("{}: {}", g.title(), names.join(", "))
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// A model option's help: `what`, then the models by group ([`groups_help`]).
pub fn option_help(what: &str) -> String {
    format!("{what}\n{}", groups_help())
}

/// Every model name, comma-separated (for help texts and errors).
pub fn names_list() -> String {
    MODELS.iter().map(|m| m.name).collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_served_topics_are_in_the_table() {
        let mut seen = std::collections::BTreeSet::new();
        for m in MODELS {
            assert!(seen.insert(m.name), "{} twice", m.name);
            assert!(m.name.len() <= 16, "{} does not fit a Name16", m.name);
            if let Some(t) = m.served_on {
                assert!(topics::FrameKind::of_topic(t).is_some(), "{t} is not in the topic table");
            }
        }
        assert!(model("unet").unwrap().is_grid_based());
        assert_eq!(served_on("unet-delta"), Some(topics::GRID_UNET.name));
        let gnn_node = model("gnn-node").unwrap();
        assert!(!gnn_node.is_grid_based() && gnn_node.served_on == Some(topics::WARM_GNN.name));
        assert!(model("nope").is_none());
    }

    #[test]
    fn every_group_is_listed_in_the_help_and_references_are_never_product() {
        let help = groups_help();
        assert_eq!(help.lines().count(), 3, "{help}");
        assert!(help.lines().next().unwrap().contains("builtin") && help.contains("gnn-node"));
        for m in MODELS {
            assert!(help.contains(m.name), "{} missing from the help", m.name);
            // A model that reads the oracle can never be what a simulator runs.
            if m.about.starts_with("oracle") || m.name.starts_with("copy") {
                assert_eq!(m.group, ModelGroup::Reference, "{}", m.name);
            }
        }
    }

    #[test]
    fn parameters_parse_with_defaults_and_bounds() {
        let (m, p) = parse("blend:0.75").unwrap();
        assert_eq!((m.name, p), ("blend", Some(0.75)));
        assert_eq!(parse("blend").unwrap().1, Some(0.5));
        assert_eq!(parse("builtin").unwrap().1, None);
        assert!(parse("blend:1.5").unwrap_err().contains("[0, 1]"));
        assert!(parse("blend:x").is_err());
        assert!(parse("builtin:3").unwrap_err().contains("no parameter"));
        assert!(parse("nope:1").unwrap_err().contains("unknown"));
        // Checked on the name the statistics carry, not on what was typed.
        assert!(parse("extrapolate:.125").unwrap_err().contains("`extrapolate:0.125`, longer than 16 bytes"));
        assert_eq!(parse("extrapolate:.25").unwrap().1, Some(0.25));
        assert_eq!(spec_name(m, Some(0.75)), "blend:0.75");
        // Names must fit the 16-byte name of the statistics.
        assert!(parse("extrapolate:0.25").is_ok());
        assert!(parse("extrapolate:0.125").unwrap_err().contains("16 bytes"));
    }

    #[test]
    fn an_external_model_is_named_by_its_user() {
        let (m, p) = parse("external:my-net2").unwrap();
        assert_eq!((m.name, p, m.served_on), (EXTERNAL, None, Some(topics::WARM_EXTERNAL.name)));
        assert_eq!(canonical_name("external:my-net2").unwrap(), "my-net2");
        assert_eq!(canonical_name("blend").unwrap(), "blend:0.5");
        assert!(parse("external").unwrap_err().contains("external:NAME"));
        for bad in ["external:", "external:Py", "external:2py", "external:a_b", "external:seventeen-bytes-x"] {
            assert!(parse(bad).unwrap_err().contains("1 to 16"), "{bad}");
        }
        assert!(parse("external:builtin").unwrap_err().contains("built-in"));
    }
}
