//! Where a model came from ([`Provenance`]): free text the exporter records.

use super::*;

/// Where a model came from, recorded by the exporter: free text for people and tools
/// (`nemm inspect` prints it); the estimator never reads it. Each field is printable: no
/// control characters (so each prints as one line). Empty means unknown.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Provenance {
    /// The command that trained and exported the model.
    pub command: heapless::String<PROVENANCE_COMMAND_LEN>,
    /// The training data: a dataset path or a description of a generated dataset.
    pub dataset: heapless::String<PROVENANCE_DATASET_LEN>,
    /// The source revision of the trainer (e.g. a git commit).
    pub commit: heapless::String<PROVENANCE_COMMIT_LEN>,
}

impl Provenance {
    /// No provenance recorded.
    pub const fn empty() -> Self {
        Self {
            command: heapless::String::new(),
            dataset: heapless::String::new(),
            commit: heapless::String::new(),
        }
    }

    /// A provenance with each text cut to its field's capacity (at a character boundary)
    /// and control characters replaced by spaces, so that it always validates.
    pub fn new(command: &str, dataset: &str, commit: &str) -> Self {
        fn fit<const N: usize>(s: &str) -> heapless::String<N> {
            let mut out = heapless::String::new();
            for c in s.chars() {
                let c = if c.is_control() { ' ' } else { c };
                if out.push(c).is_err() {
                    break;
                }
            }
            out
        }
        Self {
            command: fit(command),
            dataset: fit(dataset),
            commit: fit(commit),
        }
    }

    /// True if nothing is recorded.
    pub fn is_empty(&self) -> bool {
        self.command.is_empty() && self.dataset.is_empty() && self.commit.is_empty()
    }

    /// Checks that no field holds a control character.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (text, field) in [
            (self.command.as_str(), "provenance.command"),
            (self.dataset.as_str(), "provenance.dataset"),
            (self.commit.as_str(), "provenance.commit"),
        ] {
            if text.chars().any(char::is_control) {
                return Err(ModelError::ControlCharacter { field });
            }
        }
        Ok(())
    }
}
