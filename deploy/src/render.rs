//! `selkd render`: one episode of a trained actor (or of random actions) drawn to an animated
//! GIF, or to a PNG strip of a few frames, so that a person can see what the robot does.
//!
//! The env says what is in its world ([`selkd_envs::Env::scene`]) and how long a step lasts
//! ([`selkd_envs::Env::control_dt`]); [`selkd_render`] draws it. The camera's distance (the
//! scene's extent) and height (its focus) are fixed by the first frame, and it follows the
//! scene's focus sideways (a running robot stays in the picture while the checkered floor shows
//! it moving).
//!
//! A Gymnasium env (`gymnasium:<id>`) draws itself instead: it is made with
//! `render_mode="rgb_array"` ([`selkd_gymnasium::make_drawing`]) and its frames, scaled to fit
//! `--size` where they come at another size, are the pictures.

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use rand::{Rng, SeedableRng};
use selkd_envs::scene::Scene;
use selkd_envs::{EnvOptions, Picture};
use selkd_learner::checkpoint::{load_actor, LoadedActor};
use selkd_learner::config::Config;
use selkd_render::{render, Camera};
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Env to draw (default: the run's or the checkpoint's env); `gymnasium:<id>` draws with the
    /// env's own `rgb_array`.
    #[arg(long)]
    env: Option<String>,
    /// The env's options as JSON (`{"g": 12.0}`) or TOML (`g = 12.0`); default: the run's.
    #[arg(long)]
    env_options: Option<String>,
    /// A checkpoint directory (RUN/checkpoints/NAME) or a model.safetensors file.
    #[arg(long, conflicts_with = "run")]
    checkpoint: Option<PathBuf>,
    /// A run directory: its env and options (config.toml) and its latest checkpoint.
    #[arg(long)]
    run: Option<PathBuf>,
    /// Which actor of the checkpoint acts (default: the checkpoint's best by its ranking).
    #[arg(long)]
    actor: Option<usize>,
    /// Episode seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop after this many steps (default: the env's time limit); an episode that ends
    /// earlier stops there.
    #[arg(long)]
    steps: Option<usize>,
    /// Draw every E-th step (default: about 25 frames per second of simulated time).
    #[arg(long)]
    every: Option<usize>,
    /// Output file: .gif (animation) or .png (a strip of a few frames).
    #[arg(long, default_value = "render.gif")]
    out: PathBuf,
    /// Picture size of one frame, WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    size: String,
    /// Frames in a PNG strip.
    #[arg(long, default_value_t = 6)]
    strip_frames: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Gif,
    Png,
}

fn parse_size(s: &str) -> Result<(usize, usize)> {
    let bad = || anyhow!("--size {s}: expected WIDTHxHEIGHT, each from 16 to 4096, e.g. 320x240");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (usize, usize) = (
        w.trim().parse().map_err(|_| bad())?,
        h.trim().parse().map_err(|_| bad())?,
    );
    if !(16..=4096).contains(&w) || !(16..=4096).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

fn format_of(out: &Path) -> Result<Format> {
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("gif") => Ok(Format::Gif),
        Some("png") => Ok(Format::Png),
        _ => bail!(
            "--out {}: unknown picture format; end the file name in .gif (animation) or .png (strip of frames)",
            out.display()
        ),
    }
}

/// `--env-options` as JSON (`{"g": 12.0}`) or TOML (`g = 12.0`), several TOML keys on one line
/// separated by commas (`substeps = 40, solver_iterations = 2`, a TOML inline table's body) or
/// by newlines.
pub fn parse_env_options(text: &str) -> Result<EnvOptions> {
    if text.trim_start().starts_with('{') {
        return serde_json::from_str(text)
            .map_err(|e| anyhow!("--env-options is not a JSON object of options: {e}"));
    }
    let e = match toml::from_str(text) {
        Ok(options) => return Ok(options),
        Err(e) => e,
    };
    #[derive(serde::Deserialize)]
    struct Inline {
        o: EnvOptions,
    }
    // Only when the lines do not parse, so a key's own error (an unknown key, a bad value) is
    // reported as the lines' error.
    match toml::from_str::<Inline>(&format!("o = {{ {} }}", text.trim())) {
        Ok(i) => Ok(i.o),
        Err(_) => Err(anyhow!(
            "--env-options is neither a JSON object nor TOML (`key = value`, several keys \
             separated by commas or newlines): {}",
            e.message().trim()
        )),
    }
}

pub fn run(args: RenderArgs) -> Result<()> {
    // Every error is one line that says what to change.
    run_inner(args).map_err(|e| anyhow!("{}", format!("{e:#}").replace('\n', " ")))
}

fn run_inner(args: RenderArgs) -> Result<()> {
    let (w, h) = parse_size(&args.size)?;
    let format = format_of(&args.out)?;
    if args.every == Some(0) || args.steps == Some(0) || args.strip_frames == 0 {
        bail!("--every, --steps and --strip-frames must be at least 1");
    }

    // Where the policy and the env's defaults come from.
    let (run_config, checkpoint) = match (&args.run, &args.checkpoint) {
        (Some(run), _) => {
            let path = run.join("config.toml");
            let text = std::fs::read_to_string(&path).with_context(|| {
                format!(
                    "--run {}: not a run directory (no config.toml)",
                    run.display()
                )
            })?;
            let cfg = Config::from_toml_with_overrides(&text, &[])
                .with_context(|| format!("reading {}", path.display()))?;
            let checkpoint = crate::eval::latest_checkpoint(run).ok_or_else(|| {
                anyhow!(
                    "--run {}: no checkpoint yet (no checkpoints/latest or checkpoints/final); let the run write one, or drop --run to draw random actions",
                    run.display()
                )
            })?;
            (Some(cfg), Some(checkpoint))
        }
        (None, Some(c)) => (None, Some(c.clone())),
        (None, None) => (None, None),
    };
    let loaded: Option<LoadedActor> = match &checkpoint {
        Some(c) => Some(load_actor(c, args.actor)?),
        None => {
            if args.actor.is_some() {
                bail!("--actor needs a policy: add --checkpoint DIR or --run RUN_DIR");
            }
            None
        }
    };
    let config = run_config.or_else(|| {
        loaded
            .as_ref()
            .and_then(|l| l.state.as_ref().map(|s| s.config.clone()))
    });
    let env_name = match (&args.env, &config) {
        (Some(e), _) => e.clone(),
        (None, Some(c)) => c.run.env.clone(),
        (None, None) => bail!(
            "which env? pass --env NAME ({}, or gymnasium:<id>), or --run RUN_DIR / --checkpoint DIR of a run",
            selkd_envs::names().join(", ")
        ),
    };
    let options = match (&args.env_options, &config) {
        (Some(t), _) => parse_env_options(t)?,
        // The run's options belong to the run's env.
        (None, Some(c)) if c.run.env == env_name => c.env_options.clone(),
        _ => EnvOptions::new(),
    };
    let mut env = if env_name.starts_with(selkd_gymnasium::PREFIX) {
        selkd_gymnasium::make_drawing(&env_name, &options, w, h)?
    } else {
        selkd_envs::make_with(&env_name, &options)?
    };
    let spec = env.spec().clone();
    if let Some(l) = &loaded {
        let layout = l.actor.layout();
        if layout.obs_dim != spec.obs_dim || layout.act_dim != spec.act_dim {
            bail!(
                "the checkpoint's actor takes {} observations and gives {} actions, but env `{}` has {} and {}; pass the run's env with --env (or use --run RUN_DIR)",
                layout.obs_dim,
                layout.act_dim,
                spec.id,
                spec.obs_dim,
                spec.act_dim
            );
        }
    }
    let dt = env.control_dt().unwrap_or(0.04);
    let every = args
        .every
        .unwrap_or_else(|| ((0.04 / dt).round() as usize).max(1));
    let steps = args.steps.unwrap_or(spec.max_episode_steps);

    // The episode.
    let started = std::time::Instant::now();
    let mut obs = env.reset(Some(args.seed));
    let snap = |env: &dyn selkd_envs::Env| -> Result<Frame> {
        if let Some(scene) = env.scene() {
            return Ok(Frame::Scene(scene));
        }
        match env.picture() {
            Some(p) => Ok(Frame::Picture(p.map_err(|e| anyhow!(e))?)),
            None => bail!(
                "env `{}` cannot be drawn yet (it has no Env::scene)",
                spec.id
            ),
        }
    };
    let mut frames: Vec<Frame> = vec![snap(env.as_ref())?];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(args.seed ^ 0x5eed_fac7_10a5);
    let (mut ret, mut taken, mut success, mut ended) = (0.0, 0, None, "time limit");
    for t in 0..steps {
        let action: Vec<f32> = match &loaded {
            Some(l) => l.actor.mean_action(&obs),
            None => (0..spec.act_dim)
                .map(|_| rng.gen_range(-1.0f32..=1.0))
                .collect(),
        };
        let s = env.step(&action);
        ret += s.reward;
        taken = t + 1;
        success = s.success.or(success);
        let done = s.terminated || s.truncated;
        if (t + 1) % every == 0 || done || t + 1 == steps {
            frames.push(snap(env.as_ref())?);
        }
        obs = s.obs;
        if done {
            ended = if s.terminated {
                "terminated"
            } else {
                "time limit"
            };
            break;
        }
    }
    if taken == steps && taken < spec.max_episode_steps {
        ended = "--steps";
    }

    // The pictures.
    let pictures = |indices: &[usize]| -> Vec<Vec<u8>> {
        indices
            .iter()
            .map(|&i| match (&frames[0], &frames[i]) {
                (Frame::Scene(first), Frame::Scene(s)) => {
                    render(s, &Camera::following(first, s), w, h)
                }
                (_, Frame::Picture(p)) => fit(p, w, h),
                (Frame::Picture(_), Frame::Scene(_)) => unreachable!("an env draws one way"),
            })
            .collect()
    };
    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    let shown = match format {
        Format::Gif => {
            let all: Vec<usize> = (0..frames.len()).collect();
            let delay_cs = ((dt * every as f64 * 100.0).round() as u16).max(2);
            write_gif(&args.out, w, h, &pictures(&all), delay_cs)?;
            all.len()
        }
        Format::Png => {
            let n = args.strip_frames.min(frames.len());
            let idx: Vec<usize> = (0..n)
                .map(|k| {
                    if n == 1 {
                        0
                    } else {
                        k * (frames.len() - 1) / (n - 1)
                    }
                })
                .collect();
            write_strip(&args.out, w, h, &pictures(&idx))?;
            n
        }
    };
    let who = match &loaded {
        Some(l) => format!("actor {} of {}", l.index, l.actors),
        None => "random actions".to_string(),
    };
    let success = match success {
        Some(true) => ", success",
        Some(false) => ", no success",
        None => "",
    };
    eprintln!(
        "selkd: wrote {} ({shown} frames of {w}x{h}): {} with {who}, seed {}, {taken} steps (ended by {ended}), return {ret:.1}{success}, {:.1} s",
        args.out.display(),
        spec.id,
        args.seed,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// One frame: a scene for our ray caster, or a picture a Gymnasium env drew.
enum Frame {
    Scene(Scene),
    Picture(Picture),
}

/// `p` scaled (nearest pixel) to fit `w` × `h` with its proportions kept, centred on the dark
/// gap colour of the strips.
fn fit(p: &Picture, w: usize, h: usize) -> Vec<u8> {
    let mut out = vec![40u8; w * h * 3];
    if p.width == 0 || p.height == 0 {
        return out;
    }
    let scale = (w as f64 / p.width as f64).min(h as f64 / p.height as f64);
    let (sw, sh) = (
        ((p.width as f64 * scale).round() as usize).clamp(1, w),
        ((p.height as f64 * scale).round() as usize).clamp(1, h),
    );
    let (x0, y0) = ((w - sw) / 2, (h - sh) / 2);
    for y in 0..sh {
        let py = (y * p.height / sh).min(p.height - 1);
        for x in 0..sw {
            let px = (x * p.width / sw).min(p.width - 1);
            let src = 3 * (py * p.width + px);
            let dst = 3 * ((y0 + y) * w + x0 + x);
            out[dst..dst + 3].copy_from_slice(&p.rgb[src..src + 3]);
        }
    }
    out
}

fn write_gif(out: &Path, w: usize, h: usize, frames: &[Vec<u8>], delay_cs: u16) -> Result<()> {
    let file = std::fs::File::create(out).with_context(|| format!("creating {}", out.display()))?;
    let mut enc = gif::Encoder::new(std::io::BufWriter::new(file), w as u16, h as u16, &[])
        .context("writing the GIF")?;
    enc.set_repeat(gif::Repeat::Infinite)
        .context("writing the GIF")?;
    for rgb in frames {
        // NeuQuant per frame: shading needs more than a fixed palette's steps.
        let mut frame = gif::Frame::from_rgb_speed(w as u16, h as u16, rgb, 20);
        frame.delay = delay_cs;
        enc.write_frame(&frame).context("writing the GIF")?;
    }
    Ok(())
}

/// The frames side by side, with a thin dark gap between them.
fn write_strip(out: &Path, w: usize, h: usize, frames: &[Vec<u8>]) -> Result<()> {
    const GAP: usize = 2;
    let n = frames.len();
    let total_w = n * w + (n - 1) * GAP;
    let mut img = vec![40u8; total_w * h * 3];
    for (k, f) in frames.iter().enumerate() {
        let x0 = k * (w + GAP);
        for y in 0..h {
            let dst = 3 * (y * total_w + x0);
            img[dst..dst + 3 * w].copy_from_slice(&f[3 * y * w..3 * (y + 1) * w]);
        }
    }
    let file = std::fs::File::create(out).with_context(|| format!("creating {}", out.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), total_w as u32, h as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().context("writing the PNG")?;
    writer.write_image_data(&img).context("writing the PNG")?;
    writer.finish().context("writing the PNG")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_extension_and_options_are_checked_with_one_line_errors() {
        assert_eq!(parse_size("320x240").unwrap(), (320, 240));
        for bad in ["320", "0x240", "axb", "320x99999"] {
            let e = parse_size(bad).unwrap_err().to_string();
            assert!(e.contains("--size") && e.contains("WIDTHxHEIGHT"), "{e}");
        }
        assert_eq!(format_of(Path::new("a/b.GIF")).unwrap(), Format::Gif);
        assert_eq!(format_of(Path::new("b.png")).unwrap(), Format::Png);
        let e = format_of(Path::new("b.mp4")).unwrap_err().to_string();
        assert!(e.contains(".gif") && e.contains(".png"), "{e}");
        let json = parse_env_options(r#"{"g": 12.0}"#).unwrap();
        let toml = parse_env_options("g = 12.0").unwrap();
        assert_eq!(json, toml);
        assert!(parse_env_options("g = = 1").is_err());
        // Several keys on one command line: commas (an inline table's body) or newlines.
        let commas = parse_env_options("g = 12.0, substeps = 40").unwrap();
        let lines = parse_env_options("g = 12.0\nsubsteps = 40").unwrap();
        assert_eq!(commas, lines);
        assert_eq!(commas.len(), 2, "{commas:?}");
        let e = parse_env_options("g = 12.0, substeps")
            .unwrap_err()
            .to_string();
        assert!(e.contains("commas or newlines"), "{e}");
    }

    #[test]
    fn a_picture_of_another_size_is_scaled_to_fit_and_centred() {
        // 2 × 1: red, blue. Into 8 × 8: 8 × 4 in the middle rows, the rest the gap colour.
        let p = Picture {
            width: 2,
            height: 1,
            rgb: vec![255, 0, 0, 0, 0, 255],
        };
        let out = fit(&p, 8, 8);
        let px = |x: usize, y: usize| &out[3 * (y * 8 + x)..3 * (y * 8 + x) + 3];
        assert_eq!(px(0, 0), [40, 40, 40]);
        assert_eq!(px(0, 2), [255, 0, 0]);
        assert_eq!(px(3, 5), [255, 0, 0]);
        assert_eq!(px(4, 2), [0, 0, 255]);
        assert_eq!(px(7, 5), [0, 0, 255]);
        assert_eq!(px(7, 6), [40, 40, 40]);
        // The same size is copied as it is.
        assert_eq!(fit(&p, 2, 1), p.rgb);
    }
}
