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

/// The most bytes a text input (a CSV of points or surfaces, a spectra file) may have.
pub(crate) const MAX_TEXT_INPUT: u64 = 256 << 20;

/// Reads a file a user named on the command line (`what` says which, e.g. `--points`): a
/// regular file of at most `max_bytes`; a device, a pipe or a larger file is refused in one line
/// instead of being read without end.
pub(crate) fn read_input(path: &Path, what: &str, max_bytes: u64) -> anyhow::Result<Vec<u8>> {
    radiant::scene::read_regular_file(path, max_bytes)
        .map_err(|e| anyhow::anyhow!("cannot read {what} {}: {e}", path.display()))
}

/// [`read_input`] for text: UTF-8 of at most [`MAX_TEXT_INPUT`] bytes.
pub(crate) fn read_text(path: &Path, what: &str) -> anyhow::Result<String> {
    String::from_utf8(read_input(path, what, MAX_TEXT_INPUT)?).map_err(|_| {
        anyhow::anyhow!(
            "cannot read {what} {}: it is not UTF-8 text",
            path.display()
        )
    })
}

/// The per-surface reference for a bake: a given CSV, or the one shipped with a builtin scene.
pub fn reference_for(
    scene: &SceneArgs,
    given: Option<&Path>,
) -> anyhow::Result<Option<NamedReference>> {
    if let Some(path) = given {
        let text = read_text(path, "reference")?;
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

/// The log target of progress lines. The default log filter lets it through at `info` when
/// standard error is not a terminal, where the progress bars are hidden: a run in a pipeline,
/// under `nohup` or in CI still says how far it is.
pub(crate) const PROGRESS: &str = "radiant::progress";

/// Seconds between progress lines in the log when `RADIANT_PROGRESS_SECONDS` does not say.
const PROGRESS_SECONDS: f64 = 5.0;

/// Driver chatter wgpu relays from probing for adapters (the Vulkan loader's messages, EGL's
/// platform attempts), logged as errors though nothing failed: off unless `RUST_LOG` asks. A
/// real failure still reaches the user as Radiant's own one-line error.
const DRIVER_NOISE: &str = "wgpu_hal::vulkan::instance=off,wgpu_hal::gles::egl=off";

/// The default log filter (`RUST_LOG` replaces it): warnings, and the progress lines where no
/// bar shows them; not the drivers' probing ([`DRIVER_NOISE`]).
pub(crate) fn default_log_filter(stderr_is_terminal: bool) -> String {
    if stderr_is_terminal {
        format!("warn,{DRIVER_NOISE}")
    } else {
        format!("warn,{DRIVER_NOISE},{PROGRESS}=info")
    }
}

/// When a long phase's progress goes to the log: at most one line every
/// `RADIANT_PROGRESS_SECONDS` seconds (default 5; 0: every report), the first that long after
/// the phase began.
pub(crate) struct ProgressLog {
    every: f64,
    last: std::sync::Mutex<std::time::Instant>,
}

impl ProgressLog {
    /// From `RADIANT_PROGRESS_SECONDS`, or the default where it is unset or not a number of
    /// seconds.
    pub(crate) fn new() -> ProgressLog {
        let every = std::env::var("RADIANT_PROGRESS_SECONDS").ok();
        ProgressLog::every(parse_progress_seconds(every.as_deref()))
    }

    /// A line at most every `seconds`.
    pub(crate) fn every(seconds: f64) -> ProgressLog {
        ProgressLog {
            every: seconds,
            last: std::sync::Mutex::new(std::time::Instant::now()),
        }
    }

    /// Whether a line is due now; if so, the next is due `every` seconds from now.
    pub(crate) fn due(&self) -> bool {
        let Ok(mut last) = self.last.lock() else {
            return false;
        };
        if last.elapsed().as_secs_f64() < self.every {
            return false;
        }
        *last = std::time::Instant::now();
        true
    }
}

/// What is wrong with `RADIANT_PROGRESS_SECONDS` when it is set to something that is not a
/// number of seconds (the default is used then, and the command warns once): `None` when it is
/// unset or good.
pub(crate) fn progress_seconds_problem(value: Option<&str>) -> Option<String> {
    let v = value?;
    let good = v
        .trim()
        .parse::<f64>()
        .is_ok_and(|s| s.is_finite() && s >= 0.0);
    (!good).then(|| {
        format!(
            "RADIANT_PROGRESS_SECONDS={v:?} is not a number of seconds (0 or more): \
             progress goes to the log every {PROGRESS_SECONDS} s"
        )
    })
}

/// `RADIANT_PROGRESS_SECONDS`: a finite number of seconds, at least 0; anything else gives
/// the default.
fn parse_progress_seconds(value: Option<&str>) -> f64 {
    value
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0)
        .unwrap_or(PROGRESS_SECONDS)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_lines_are_spaced_and_shown_where_no_bar_is() {
        assert_eq!(parse_progress_seconds(None), PROGRESS_SECONDS);
        assert_eq!(parse_progress_seconds(Some(" 30 ")), 30.0);
        assert_eq!(parse_progress_seconds(Some("0")), 0.0);
        for bad in ["-1", "nan", "inf", "soon", ""] {
            assert_eq!(parse_progress_seconds(Some(bad)), PROGRESS_SECONDS, "{bad}");
            let problem = progress_seconds_problem(Some(bad)).expect("a warning");
            assert!(problem.contains("RADIANT_PROGRESS_SECONDS"), "{problem}");
        }
        for good in [None, Some("0"), Some(" 30 "), Some("2.5")] {
            assert_eq!(progress_seconds_problem(good), None, "{good:?}");
        }
        let every = ProgressLog::every(0.0);
        assert!(every.due() && every.due());
        let rarely = ProgressLog::every(3600.0);
        assert!(
            !rarely.due(),
            "the first line comes a whole interval after the start"
        );
        assert_eq!(default_log_filter(true), format!("warn,{DRIVER_NOISE}"));
        let piped = default_log_filter(false);
        assert!(piped.contains(&format!("{PROGRESS}=info")), "{piped}");
        assert!(
            tracing_subscriber::EnvFilter::try_new(&piped).is_ok(),
            "{piped}"
        );
    }
}
