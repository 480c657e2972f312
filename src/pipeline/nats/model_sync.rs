//! The model across workers: versions in the object store, the current one in the key-value
//! bucket.
//!
//! A model version travels as a [`ModelBundle`] (the files a data folder holds for it:
//! manifest, model file, the reference's mesh and label map) under its content key; the
//! bucket maps `vN` to that key and `current` to the newest version. A worker whose trainer
//! saves a new version publishes it (a compare-and-set on `current`, so two trainers cannot
//! both move it to the same number); every worker follows `current` and swaps the new version
//! into its live model atomically, exactly as the in-process trainer does. A job keeps the
//! model snapshot it started with, and its result names that version.
//!
//! The trainer is a single writer: the worker that runs it holds the lease `trainer` in the
//! bucket (a key created only if absent, refreshed while it runs); a second trainer waits and
//! takes over when the lease is not refreshed for [`LEASE_S`] seconds.

use std::{
    path::Path,
    sync::Arc,
    time::{Duration, Instant},
};

use super::{wire, wire::ModelBundle, Nats};
use crate::{
    geodesic::HeatParams,
    pipeline::{
        model::{load_live_model_for, LiveModel, ModelState, ServeNeeds},
        shutdown::Shutdown,
        store::{latest_manifest, stored_shapes, DataDir, ModelManifest},
    },
};

/// Seconds after which a trainer's lease that was not refreshed may be taken over.
pub const LEASE_S: u64 = 10;

/// The current model version in the bucket (0: none).
pub async fn current_version(nats: &Nats) -> Result<(u64, u64), String> {
    match nats.model_bucket().entry("current").await.map_err(|e| format!("model bucket: {e}"))? {
        Some(e) if !e.value.is_empty() => {
            let v = std::str::from_utf8(&e.value).ok().and_then(|t| t.trim().parse::<u64>().ok());
            v.map(|v| (v, e.revision))
                .ok_or_else(|| "model bucket: `current` is not a version number".to_string())
        }
        Some(e) => Ok((0, e.revision)),
        None => Ok((0, 0)),
    }
}

/// The bundle of the newest model version of `data` (and its manifest).
pub fn bundle_of(data: &DataDir) -> Result<Option<(ModelManifest, ModelBundle)>, String> {
    let Some(m) = latest_manifest(&data.models()) else { return Ok(None) };
    let read = |p: &Path| std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()));
    let mut files = vec![
        (
            format!("models/model-v{:06}.json", m.version),
            read(&data.models().join(format!("model-v{:06}.json", m.version)))?,
        ),
        (format!("models/{}", m.model_file), read(&data.models().join(&m.model_file))?),
    ];
    let reference =
        stored_shapes(&data.training()).into_iter().find(|s| s.name == m.reference).ok_or_else(|| {
            format!("model v{}: its reference `{}` is not in training/", m.version, m.reference)
        })?;
    for p in [&reference.mesh, &reference.labels] {
        let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        files.push((format!("training/{name}"), read(p)?));
    }
    let version = m.version;
    Ok(Some((m, ModelBundle { version, files })))
}

/// Stores the newest model version of `data` and makes it `current` if it is newer than the
/// bucket's. Returns the version now current.
pub async fn publish_model(nats: &Nats, data: &DataDir) -> Result<u64, String> {
    let Some((m, bundle)) = bundle_of(data)? else { return current_version(nats).await.map(|c| c.0) };
    let bytes = wire::encode(wire::MODEL_BUNDLE, &bundle)?;
    let blob = nats.put_blob(&bytes).await?;
    let kv = nats.model_bucket();
    let key_bytes = rmp_serde::to_vec_named(&blob).map_err(|e| e.to_string())?;
    kv.put(format!("v{}", m.version), key_bytes.into()).await.map_err(|e| format!("model bucket: {e}"))?;
    loop {
        let (current, revision) = current_version(nats).await?;
        if current >= m.version {
            return Ok(current);
        }
        let value = m.version.to_string().into_bytes().into();
        let r = if revision == 0 {
            kv.create("current", value).await.map(|_| ()).map_err(|e| e.to_string())
        } else {
            kv.update("current", value, revision).await.map(|_| ()).map_err(|e| e.to_string())
        };
        if r.is_ok() {
            tracing::info!(version = m.version, "published model v{} to the model bucket", m.version);
            return Ok(m.version);
        }
        // Another worker moved `current` meanwhile: look again.
    }
}

/// Reads model `version` from the store into `root/vN/` (a data folder of its own) and loads it.
pub async fn fetch_model(
    nats: &Nats,
    version: u64,
    root: &Path,
    needs: &ServeNeeds,
) -> Result<ModelState, String> {
    let entry = nats
        .model_bucket()
        .get(format!("v{version}"))
        .await
        .map_err(|e| format!("model bucket: {e}"))?
        .ok_or_else(|| format!("model v{version} is not in the model bucket"))?;
    let blob: wire::BlobRef =
        rmp_serde::from_slice(&entry).map_err(|e| format!("model bucket v{version}: {e}"))?;
    let bytes = nats.get_blob(&blob).await?;
    let bundle: ModelBundle = wire::decode(wire::MODEL_BUNDLE, &bytes)?;
    if bundle.version != version {
        return Err(format!("the bundle of model v{version} holds v{}", bundle.version));
    }
    let dir = root.join(format!("v{version}"));
    let needs = needs.clone();
    tokio::task::spawn_blocking(move || {
        bundle.unpack(&dir)?;
        let data = DataDir::new(&dir);
        match load_live_model_for(&data, HeatParams::default(), &needs).map_err(|e| e.to_string())? {
            Some(m) if m.version == version => Ok(m),
            Some(m) => Err(format!("model v{version}: loaded v{} instead", m.version)),
            None => Err(format!("model v{version} does not load (see the warnings)")),
        }
    })
    .await
    .map_err(|e| format!("model v{version}: {e}"))?
}

/// Keeps a worker's live model in step with the bucket until `shutdown`: a newer `current`
/// is fetched and swapped in; a newer local version (this worker's trainer saved it under
/// `data`) is published. Runs on the connection's runtime; checks every `every`.
pub fn follow(
    nats: Arc<Nats>,
    data: DataDir,
    live: Arc<LiveModel>,
    needs: ServeNeeds,
    shutdown: Shutdown,
    every: Duration,
) {
    let handle = nats.runtime.handle().clone();
    handle.spawn(async move {
        let root = data.root().join(".nats").join("models");
        let mut last_problem = Instant::now() - Duration::from_secs(60);
        loop {
            let step = async {
                let (current, _) = current_version(&nats).await?;
                let local = latest_manifest(&data.models()).map_or(0, |m| m.version);
                if local > current && live.version() == local {
                    publish_model(&nats, &data).await?;
                } else if current > live.version() {
                    let m = fetch_model(&nats, current, &root, &needs).await?;
                    tracing::info!(version = current, "switching to model v{current} from the model bucket");
                    live.publish(Arc::new(m));
                }
                Ok::<_, String>(())
            };
            if let Err(e) = step.await {
                if last_problem.elapsed() > Duration::from_secs(10) {
                    tracing::warn!("model follower: {e}");
                    last_problem = Instant::now();
                }
            }
            tokio::select! {
                _ = shutdown.triggered() => break,
                _ = tokio::time::sleep(every) => {}
            }
        }
    });
}

/// Takes the trainer lease for `holder`, waiting while another holder refreshes it; `false`
/// at shutdown. The lease is a value `HOLDER UNIX_S` in the bucket's key `trainer`.
pub async fn acquire_lease(nats: &Nats, holder: &str, shutdown: &Shutdown) -> bool {
    let kv = nats.model_bucket();
    loop {
        let now = crate::pipeline::store::unix_now();
        let value: bytes::Bytes = format!("{holder} {now}").into_bytes().into();
        match kv.entry("trainer").await {
            Ok(None) => {
                if kv.create("trainer", value).await.is_ok() {
                    return true;
                }
            }
            Ok(Some(e)) => {
                let text = String::from_utf8_lossy(&e.value).to_string();
                let mut parts = text.split_whitespace();
                let (who, at) = (
                    parts.next().unwrap_or(""),
                    parts.next().and_then(|t| t.parse::<u64>().ok()).unwrap_or(0),
                );
                if (who == holder || e.value.is_empty() || now.saturating_sub(at) > LEASE_S)
                    && kv.update("trainer", value, e.revision).await.is_ok()
                {
                    return true;
                }
            }
            Err(e) => tracing::warn!("trainer lease: {e}"),
        }
        tokio::select! {
            _ = shutdown.triggered() => return false,
            _ = tokio::time::sleep(Duration::from_secs(1)) => {}
        }
    }
}

/// Refreshes the lease every second until `shutdown` (then releases it).
pub fn keep_lease(nats: Arc<Nats>, holder: String, shutdown: Shutdown) {
    let handle = nats.runtime.handle().clone();
    handle.spawn(async move {
        let kv = nats.model_bucket();
        loop {
            tokio::select! {
                _ = shutdown.triggered() => break,
                _ = tokio::time::sleep(Duration::from_secs(1)) => {}
            }
            let now = crate::pipeline::store::unix_now();
            if let Ok(Some(e)) = kv.entry("trainer").await {
                if String::from_utf8_lossy(&e.value).split_whitespace().next() == Some(holder.as_str()) {
                    let _ =
                        kv.update("trainer", format!("{holder} {now}").into_bytes().into(), e.revision).await;
                } else {
                    tracing::error!("the trainer lease was taken over by another worker");
                }
            }
        }
        let _ = kv.delete("trainer").await;
    });
}
