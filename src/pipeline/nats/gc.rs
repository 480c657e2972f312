//! Garbage collection of the object store: objects no message refers to any more, and model
//! versions older than the last few.
//!
//! The object store only grows: every job leaves its meshes, spectra, predictions, matches and
//! maps there (~30 MB per 20K-vertex scan) after its messages are acknowledged and gone. An
//! object is kept while
//! - a message still waiting, held or dead-lettered in one of the pipeline's streams refers to
//!   it (its payload is read for object keys), or
//! - it is the bundle of a kept model version (the current one, the `keep_models − 1` before it,
//!   and any version a waiting message names), or
//! - it is younger than `grace` (a stage stores its output's objects before it publishes the
//!   message that names them; a collection in between must not take them).
//!
//! Everything else is deleted, and the bucket's keys of the model versions deleted with it.

use std::{collections::HashSet, time::Duration};

use futures_util::StreamExt;

use super::{model_sync, token, wire::BlobRef, Nats};

/// What a collection found and did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GcReport {
    /// Messages read in the pipeline's streams.
    pub messages: u64,
    /// Objects they refer to.
    pub referenced: usize,
    /// Objects in the store before.
    pub objects: usize,
    /// Objects deleted.
    pub deleted: usize,
    /// Their bytes.
    pub deleted_bytes: u64,
    /// Model versions deleted.
    pub deleted_models: Vec<u64>,
}

/// Collects object keys (`{key, size}` maps) and model versions (`model_version`) anywhere in
/// a decoded message.
fn references(v: &serde_json::Value, keys: &mut HashSet<String>, versions: &mut HashSet<u64>) {
    match v {
        serde_json::Value::Object(m) => {
            if let (Some(serde_json::Value::String(k)), Some(s)) = (m.get("key"), m.get("size")) {
                if s.is_u64() && k.len() == 64 && k.bytes().all(|b| b.is_ascii_hexdigit()) {
                    keys.insert(k.clone());
                }
            }
            if let Some(n) = m.get("model_version").and_then(|n| n.as_u64()) {
                versions.insert(n);
            }
            for x in m.values() {
                references(x, keys, versions);
            }
        }
        serde_json::Value::Array(a) => {
            for x in a {
                references(x, keys, versions);
            }
        }
        _ => {}
    }
}

/// Deletes what nothing needs any more (see the module's notes); `keep_models` ≥ 1.
pub async fn collect(nats: &Nats, keep_models: u64, grace: Duration) -> Result<GcReport, String> {
    let mut report = GcReport::default();
    let prefix = format!("{}_", token(&nats.settings.prefix));
    let mut keys = HashSet::new();
    let mut versions = HashSet::new();
    // The pipeline's streams: its edges and its dead letters.
    let mut names = nats.js.stream_names();
    let mut streams = Vec::new();
    while let Some(n) = names.next().await {
        let n = n.map_err(|e| format!("cannot list the streams: {e}"))?;
        if n.starts_with(&prefix) {
            streams.push(n);
        }
    }
    for name in streams {
        let mut s = nats.js.get_stream(&name).await.map_err(|e| format!("stream {name}: {e}"))?;
        let state = s.info().await.map_err(|e| format!("stream {name}: {e}"))?.state.clone();
        if state.messages == 0 {
            continue;
        }
        for seq in state.first_sequence..=state.last_sequence {
            // A gap (an acknowledged message of a work queue) is simply not there.
            let Ok(m) = s.get_raw_message(seq).await else { continue };
            report.messages += 1;
            match rmp_serde::from_slice::<serde_json::Value>(&m.payload) {
                Ok(v) => references(&v, &mut keys, &mut versions),
                // A message no reader understands keeps nothing: it names no object we know.
                Err(e) => tracing::debug!(stream = %name, seq, "not read for references: {e}"),
            }
        }
    }
    // Model versions: the current one and those just before it, and those messages name.
    let (current, _) = model_sync::current_version(nats).await?;
    let keep_from = current.saturating_sub(keep_models.max(1) - 1);
    let mut kv_keys = nats.kv.keys().await.map_err(|e| format!("model bucket: {e}"))?;
    let mut drop_versions = Vec::new();
    while let Some(k) = kv_keys.next().await {
        let k = k.map_err(|e| format!("model bucket: {e}"))?;
        let Some(v) = k.strip_prefix('v').and_then(|v| v.parse::<u64>().ok()) else { continue };
        let value = nats.kv.get(&k).await.map_err(|e| format!("model bucket: {e}"))?;
        let blob = value.and_then(|b| rmp_serde::from_slice::<BlobRef>(&b).ok());
        if v >= keep_from || versions.contains(&v) {
            if let Some(b) = blob {
                keys.insert(b.key);
            }
        } else {
            drop_versions.push((v, k));
        }
    }
    report.referenced = keys.len();
    // The objects.
    let now =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs() as i64);
    let mut list = nats.blobs.list().await.map_err(|e| format!("cannot list the objects: {e}"))?;
    let mut doomed = Vec::new();
    while let Some(info) = list.next().await {
        let info = info.map_err(|e| format!("cannot list the objects: {e}"))?;
        if info.deleted {
            continue;
        }
        report.objects += 1;
        let age = info.modified.map_or(0, |m| now - m.unix_timestamp());
        if !keys.contains(&info.name) && age >= grace.as_secs() as i64 {
            doomed.push((info.name, info.size as u64));
        }
    }
    for (name, size) in doomed {
        match nats.blobs.delete(&name).await {
            Ok(()) => {
                report.deleted += 1;
                report.deleted_bytes += size;
            }
            Err(e) => tracing::warn!("cannot delete object {name}: {e}"),
        }
    }
    for (v, k) in drop_versions {
        if nats.kv.purge(&k).await.is_ok() {
            report.deleted_models.push(v);
        }
    }
    report.deleted_models.sort_unstable();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn references_are_found_at_any_depth_and_nothing_else_counts() {
        let k = "a".repeat(64);
        let v = serde_json::json!({
            "job": {"key": "not-an-object-key", "id": 3},
            "body": {"Ok": {"spectral": {"shape": {"mesh": {"key": k, "size": 10}}}, "model_version": 4}},
            "other": [{"key": "b".repeat(63), "size": 1}, {"key": "c".repeat(64)}],
        });
        let (mut keys, mut versions) = (HashSet::new(), HashSet::new());
        references(&v, &mut keys, &mut versions);
        assert_eq!(keys, HashSet::from([k]));
        assert_eq!(versions, HashSet::from([4]));
    }
}
