//! The warm-start models a simulator can run, by name: the one list the simulator, the launcher's
//! evaluation, the metrics report and the nodes that serve grids agree on.

use crate::topics;

/// One warm-start model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelInfo {
    pub name: &'static str,
    /// The grid topic a grid-based model reads its warm start from (None: computed in the simulator).
    pub grid_topic: Option<&'static str>,
    pub about: &'static str,
}

impl ModelInfo {
    pub fn is_grid_based(&self) -> bool {
        self.grid_topic.is_some()
    }
}

/// Every model, in the order of the thesis's table.
pub const MODELS: &[ModelInfo] = &[
    ModelInfo { name: "none", grid_topic: None, about: "cold start: zero impulses" },
    ModelInfo { name: "builtin", grid_topic: None, about: "the previous step's impulse of each persisting contact" },
    ModelInfo { name: "copy", grid_topic: None, about: "oracle: the step's own solution" },
    ModelInfo { name: "copy0", grid_topic: None, about: "oracle rounded to 0 decimals" },
    ModelInfo { name: "copy2", grid_topic: None, about: "oracle rounded to 2 decimals" },
    ModelInfo { name: "bad", grid_topic: None, about: "a deliberately wrong warm start" },
    ModelInfo { name: "random", grid_topic: None, about: "random impulses of the solution's scale" },
    ModelInfo { name: "extrapolate", grid_topic: None, about: "linear extrapolation of the last two steps" },
    ModelInfo {
        name: "copy-grid",
        grid_topic: None,
        about: "oracle through the value-preserving grid transfer and back",
    },
    ModelInfo { name: "copy-grid-sph", grid_topic: None, about: "oracle through the thesis's grid transfer and back" },
    ModelInfo {
        name: "grid",
        grid_topic: Some(topics::GRID_CONTACTS.name),
        about: "the previous step's impulses through the SPH node's grid",
    },
    ModelInfo { name: "unet", grid_topic: Some(topics::GRID_UNET.name), about: "the U-Net's predicted impulse grid" },
];

/// The model called `name`.
pub fn model(name: &str) -> Option<&'static ModelInfo> {
    MODELS.iter().find(|m| m.name == name)
}

/// Every model name, comma-separated (for help texts and errors).
pub fn names_list() -> String {
    MODELS.iter().map(|m| m.name).collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_grid_topics_are_in_the_table() {
        let mut seen = std::collections::BTreeSet::new();
        for m in MODELS {
            assert!(seen.insert(m.name), "{} twice", m.name);
            assert!(m.name.len() <= 16, "{} does not fit a Name16", m.name);
            if let Some(t) = m.grid_topic {
                assert_eq!(topics::FrameKind::of_topic(t), Some(topics::FrameKind::Grid));
            }
        }
        assert!(model("unet").unwrap().is_grid_based());
        assert!(model("nope").is_none());
    }
}
