//! The match report (`NAME.report.json`) written by `shapeforest match` and by the daemon's
//! `match-sink`: what the map looks like (shared fields, one serde type) plus what the writer
//! adds about its inputs, timings and files.

use serde::{Deserialize, Serialize};

use crate::{forest::Prediction, regularizer::DenseMap};

/// What every match report says about the map.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapQuality {
    /// Weighted orientation agreement at the sparse matches (negative: a mirror image).
    pub orientation_score: f64,
    /// Whether the game's first equilibrium was a mirror image and was replaced.
    pub mirror_rejected: bool,
    /// Whether the forest's prediction read as a mirror image as a whole and was read through
    /// the reference's symmetry ([`DenseMap::prediction_mirrored`]).
    #[serde(default)]
    pub prediction_mirrored: bool,
    /// Whether, on a single view, the map of the game among the complete scan's candidates was
    /// kept over the one among more ([`DenseMap::alternative_kept`]).
    #[serde(default)]
    pub alternative_kept: bool,
    /// Anchors of the last round of anchor growth (0: growth off).
    pub grown_anchors: usize,
    /// Mean orientation agreement of the grown map (`null`: growth off).
    pub dense_orientation_agreement: Option<f64>,
    /// Whether growth found a mirror image and the re-oriented run replaced it.
    pub reoriented: bool,
    /// Mean of the forest's largest posterior probability per vertex.
    pub mean_forest_confidence: f64,
    /// Mean share of the trees that voted for each vertex's label.
    pub mean_forest_support: f64,
}

impl MapQuality {
    /// The quality fields of a dense map and the prediction it came from.
    pub fn of(dense: &DenseMap, prediction: &Prediction) -> Self {
        Self {
            orientation_score: dense.orientation_score,
            mirror_rejected: dense.mirror_rejected,
            prediction_mirrored: dense.prediction_mirrored,
            alternative_kept: dense.alternative_kept,
            grown_anchors: dense.grown_anchors,
            dense_orientation_agreement: dense.dense_orientation,
            reoriented: dense.reoriented,
            mean_forest_confidence: prediction.mean_confidence(),
            mean_forest_support: prediction.mean_support(),
        }
    }
}

/// A match report: the [`MapQuality`] and the writer's own fields (inputs, timings, files),
/// written as one JSON object with its keys in sorted order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MatchReport {
    /// What the map looks like.
    #[serde(flatten)]
    pub quality: MapQuality,
    /// Everything else the writer reports.
    #[serde(flatten)]
    pub details: serde_json::Map<String, serde_json::Value>,
}

impl MatchReport {
    /// A report of `dense` (from `prediction`) with `details` (a JSON object; anything else is
    /// ignored).
    pub fn new(dense: &DenseMap, prediction: &Prediction, details: serde_json::Value) -> Self {
        let details = match details {
            serde_json::Value::Object(m) => m,
            _ => serde_json::Map::new(),
        };
        Self { quality: MapQuality::of(dense, prediction), details }
    }

    /// The report as pretty JSON with a final newline, keys sorted.
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        // Through a `Value` (a sorted map): the two parts' keys interleave in one order.
        Ok(serde_json::to_string_pretty(&serde_json::to_value(self)?)? + "\n")
    }
}
