//! What every command shares: the scene, the reference it is measured against, progress
//! bars and durations.

use std::path::Path;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use radiant::radiosity::metrics;

use crate::SceneArgs;

/// A per-surface reference and where it came from.
pub type NamedReference = (String, Vec<(String, [f64; 3])>);

impl SceneArgs {
    /// What ships with the builtin scene to measure against (nothing for a file).
    pub(crate) fn shipped(&self) -> Option<metrics::ShippedReferences> {
        self.builtin.map(|b| metrics::shipped_references(b.0))
    }
}

/// The per-surface reference for a bake: a given CSV, or the one shipped with a builtin scene.
pub fn reference_for(
    scene: &SceneArgs,
    given: Option<&Path>,
) -> anyhow::Result<Option<NamedReference>> {
    if let Some(path) = given {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read reference {}", path.display()))?;
        let rows =
            metrics::parse_reference_csv(&text).with_context(|| format!("{}", path.display()))?;
        return Ok(Some((path.display().to_string(), rows)));
    }
    match scene.shipped() {
        Some(s) => Ok(Some((
            s.surfaces_source.to_string(),
            metrics::parse_reference_csv(s.surfaces)?,
        ))),
        None => Ok(None),
    }
}

/// A progress bar on a terminal; hidden otherwise.
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    if let Ok(style) =
        ProgressStyle::with_template("{spinner} {msg:24} [{bar:32}] {pos}/{len} {elapsed_precise}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

/// Seconds as a `Duration`, with a clear error instead of a panic for absurd values.
pub(crate) fn seconds(t: f64) -> anyhow::Result<std::time::Duration> {
    std::time::Duration::try_from_secs_f64(t)
        .map_err(|_| anyhow::anyhow!("{t} seconds is out of range"))
}

/// Loads the scene named by the arguments, with the sky `--sky` gives.
pub(crate) fn load_scene(args: &SceneArgs) -> anyhow::Result<(radiant::scene::Scene, String)> {
    let (mut scene, name) = match (&args.scene, &args.builtin) {
        (_, Some(b)) => (b.0.scene()?, b.0.name().to_string()),
        (Some(path), None) => {
            let scene = radiant::scene::load_gltf(path)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            (scene, path.display().to_string())
        }
        (None, None) => anyhow::bail!("give a scene file or --builtin NAME"),
    };
    apply_sky(&mut scene, args.sky.as_deref())?;
    Ok((scene, name))
}

/// Replaces the scene's sky with `--sky` (`none` removes it).
pub(crate) fn apply_sky(
    scene: &mut radiant::scene::Scene,
    sky: Option<&str>,
) -> anyhow::Result<()> {
    match sky.map(str::trim) {
        None => {}
        Some("none") => scene.sky = None,
        Some(spec) => {
            scene.sky = Some(
                radiant::scene::Sky::parse(spec, None)
                    .map_err(|e| anyhow::anyhow!("--sky {spec}: {e}"))?,
            );
        }
    }
    Ok(())
}
