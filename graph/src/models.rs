//! The graph's `models:` section: named bundles of model files, each part loaded once per graph
//! and shared by every node that names the bundle.
//!
//! ```yaml
//! models:
//!   tiny:
//!     tokenizer: {config: configs/models/tokenizer-tiny.yaml, weights: nodes/tokenizer/weights/tokenizer-tiny.bpk}
//!     world_model: {config: configs/models/world-model-tiny.yaml, weights: nodes/world_model/weights/world-model-tiny.bpk}
//! nodes:
//!   - {id: encode, kind: encode, params: {model: tiny}}
//! ```
//!
//! The runtime knows a bundle only as JSON: the application registers one checker for the
//! bundles (`Registry::models`, run by validation), and each node kind loads the part it needs
//! through `Models::load`, which keeps the first load of each (bundle, type) and hands out
//! `Arc`s to it. The encoder and the renderer of a graph thus run one tokenizer, not two copies.

use std::any::{Any, TypeId};
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use crate::registry::ParamError;

/// The field a node names its bundle with.
pub const MODEL_FIELD: &str = "model";

type Loaded = Arc<dyn Any + Send + Sync>;

/// A graph's model bundles, as checked (defaults filled in), and what has been loaded of them.
#[derive(Default)]
pub struct Models {
    bundles: BTreeMap<String, serde_json::Value>,
    /// Bundles the graph declares that failed their check: their problems are reported where
    /// they are written, so a node naming one is not refused a second time.
    refused: std::collections::BTreeSet<String>,
    loaded: Mutex<HashMap<(String, TypeId), Loaded>>,
    loads: Mutex<BTreeMap<String, usize>>,
    asked: Mutex<BTreeMap<String, usize>>,
}

impl std::fmt::Debug for Models {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Models")
            .field("bundles", &self.bundles)
            .finish_non_exhaustive()
    }
}

impl Models {
    /// Bundles by name, each the JSON object its `models:` entry resolves to.
    pub fn new(bundles: BTreeMap<String, serde_json::Value>) -> Self {
        Self {
            bundles,
            ..Self::default()
        }
    }

    /// Marks bundle `name`, declared by the graph, as refused by its check.
    pub fn refuse(&mut self, name: &str) {
        self.refused.insert(name.to_string());
    }

    /// Whether bundle `name` was declared and refused by its check.
    pub fn is_refused(&self, name: &str) -> bool {
        self.refused.contains(name)
    }

    /// No bundle: what a node built outside a graph sees.
    pub fn none() -> Self {
        Self::default()
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.bundles.keys().map(String::as_str)
    }

    pub fn bundles(&self) -> &BTreeMap<String, serde_json::Value> {
        &self.bundles
    }

    /// Bundle `name`, which must hold every part in `parts`: what a node's check asks at
    /// validation, so that a node naming a missing bundle or part is refused at its `model`
    /// field before anything loads.
    pub fn require(&self, name: &str, parts: &[&str]) -> Result<&serde_json::Value, ParamError> {
        let Some(bundle) = self.bundles.get(name) else {
            let known: Vec<&str> = self.names().collect();
            let accepted = if known.is_empty() {
                "the graph has no `models:` section; add one, e.g. `models: {tiny: {tokenizer: {config: ..., weights: ...}}}`".to_string()
            } else {
                format!(
                    "a bundle of the graph's `models:` section: {}",
                    known.join(", ")
                )
            };
            return Err(ParamError::field(
                MODEL_FIELD,
                format!("no model bundle '{name}' in the graph's `models:` section"),
            )
            .with_accepted(accepted));
        };
        for part in parts {
            if bundle.get(part).is_none_or(serde_json::Value::is_null) {
                return Err(ParamError::field(
                    MODEL_FIELD,
                    format!("model bundle '{name}' has no `{part}`, which this node runs"),
                )
                .with_accepted(format!("a bundle with `{part}:`")));
            }
        }
        Ok(bundle)
    }

    /// The `T` of bundle `name`: loaded by `load` (from the bundle's JSON) the first time a node
    /// asks for it, and shared after that.
    pub fn load<T: Any + Send + Sync>(
        &self,
        name: &str,
        load: impl FnOnce(&serde_json::Value) -> Result<T, ParamError>,
    ) -> Result<Arc<T>, ParamError> {
        let bundle = self.require(name, &[])?;
        let label = format!("{name}/{}", crate::port::short_type_name::<T>());
        *lock(&self.asked).entry(label.clone()).or_default() += 1;
        let key = (name.to_string(), TypeId::of::<T>());
        // Held while loading: nodes are built one after another, and a second asker waits for
        // the first load rather than making its own.
        let mut loaded = lock(&self.loaded);
        if let Some(found) = loaded.get(&key) {
            return Arc::clone(found)
                .downcast::<T>()
                .map_err(|_| ParamError::field(MODEL_FIELD, "a loaded model of another type"));
        }
        let made = Arc::new(load(bundle)?);
        loaded.insert(key, Arc::clone(&made) as Loaded);
        *lock(&self.loads).entry(label).or_default() += 1;
        Ok(made)
    }

    /// How many times each (bundle, type) was loaded, as `bundle/Type`: once each, by
    /// construction; a test holds it to that.
    pub fn loads(&self) -> BTreeMap<String, usize> {
        lock(&self.loads).clone()
    }

    /// How many times nodes asked for each (bundle, type), as `loads` names them.
    pub fn asked(&self) -> BTreeMap<String, usize> {
        lock(&self.asked).clone()
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    match mutex.lock() {
        Ok(guard) => guard,
        Err(poisoned) => poisoned.into_inner(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn models() -> Models {
        Models::new(BTreeMap::from([(
            "tiny".to_string(),
            serde_json::json!({"tokenizer": {"weights": "t.bpk"}, "world_model": null}),
        )]))
    }

    #[test]
    fn each_part_is_loaded_once_and_shared() {
        let models = models();
        let mut calls = 0;
        let first = models
            .load("tiny", |bundle| {
                calls += 1;
                Ok(bundle["tokenizer"]["weights"]
                    .as_str()
                    .unwrap_or("")
                    .to_string())
            })
            .unwrap();
        let second = models
            .load::<String>("tiny", |_| panic!("loaded twice"))
            .unwrap();
        assert!(Arc::ptr_eq(&first, &second));
        assert_eq!(calls, 1);
        assert_eq!(models.loads().get("tiny/String"), Some(&1));
        assert_eq!(models.asked().get("tiny/String"), Some(&2));
        // Another type of the same bundle is another part.
        let number = models.load("tiny", |_| Ok(7u32)).unwrap();
        assert_eq!(*number, 7);
        assert_eq!(models.loads().len(), 2);
    }

    #[test]
    fn a_missing_bundle_or_part_names_the_model_field() {
        let models = models();
        let error = models.require("tyni", &[]).unwrap_err();
        assert_eq!(error.field.as_deref(), Some(MODEL_FIELD));
        assert!(error.message.contains("'tyni'"), "{}", error.message);
        assert!(error.accepted.unwrap().contains("tiny"));
        let error = models.require("tiny", &["world_model"]).unwrap_err();
        assert!(error.message.contains("world_model"), "{}", error.message);
        assert!(models.require("tiny", &["tokenizer"]).is_ok());
        let error = Models::none().load("tiny", |_| Ok(1u8)).unwrap_err();
        assert!(error.accepted.unwrap().contains("no `models:`"));
    }

    #[test]
    fn a_failed_load_is_not_kept() {
        let models = models();
        assert!(
            models
                .load::<u8>("tiny", |_| Err(ParamError::field("model", "bad")))
                .is_err()
        );
        assert_eq!(*models.load("tiny", |_| Ok(3u8)).unwrap(), 3);
    }
}
