//! `selkd render` through the real binary: episodes of random actions and of a trained run's
//! actor drawn to GIFs and PNG strips that decode, with the frames, sizes and timing asked for.

mod common;
use common::*;
use std::path::Path;
use std::process::{Command, Output};

fn render(args: &[&str]) -> Output {
    let mut c = Command::new(bin("selkd"));
    c.arg("render").args(args);
    run(c)
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "selkd render failed: {err}");
    err
}

/// The number just before `word` in selkd's summary line, e.g. "(12 frames".
fn number_before(text: &str, word: &str) -> usize {
    let i = text
        .find(word)
        .unwrap_or_else(|| panic!("no `{word}` in {text}"));
    text[..i]
        .split(|c: char| !c.is_ascii_digit())
        .rfind(|s| !s.is_empty())
        .unwrap()
        .parse()
        .unwrap()
}

/// Every frame of a GIF as RGBA, with its delay (1/100 s); checks the size.
fn gif_frames(path: &Path, w: u16, h: u16) -> Vec<(Vec<u8>, u16)> {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts.read_info(std::fs::File::open(path).unwrap()).unwrap();
    assert_eq!((d.width(), d.height()), (w, h), "{}", path.display());
    let mut frames = vec![];
    while let Some(f) = d.read_next_frame().unwrap() {
        assert_eq!((f.width, f.height), (w, h));
        frames.push((f.buffer.to_vec(), f.delay));
    }
    frames
}

fn png_size(path: &Path) -> (u32, u32, Vec<u8>) {
    let d = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = d.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn random_hopper_and_fpc_assembly_render_to_gif_and_png() {
    let dir = temp_dir("render");
    for (env, steps, every, delay) in [("hopper", 40, 4, 3), ("fpc-assembly", 12, 1, 5)] {
        let gif_path = dir.join(format!("{env}.gif"));
        let out = render(&[
            "--env",
            env,
            "--steps",
            &steps.to_string(),
            "--every",
            &every.to_string(),
            "--size",
            "96x72",
            "--seed",
            "3",
            "--out",
            gif_path.to_str().unwrap(),
        ]);
        let err = ok(&out);
        assert!(err.contains("random actions"), "{err}");
        let frames = gif_frames(&gif_path, 96, 72);
        // The reset, then every E-th step and the last one.
        let taken = number_before(&err, " steps");
        assert_eq!(number_before(&err, " frames"), frames.len(), "{err}");
        assert_eq!(frames.len(), 1 + taken.div_ceil(every), "{env}: {err}");
        assert!(frames.len() >= 3, "{env}: {err}");
        assert!(
            frames.iter().all(|(_, d)| *d == delay),
            "{env}: frame delay"
        );
        assert_ne!(
            frames[0].0,
            frames.last().unwrap().0,
            "{env}: nothing moved"
        );

        let png_path = dir.join(format!("{env}.png"));
        let out = render(&[
            "--env",
            env,
            "--steps",
            &steps.to_string(),
            "--size",
            "96x72",
            "--strip-frames",
            "3",
            "--seed",
            "3",
            "--out",
            png_path.to_str().unwrap(),
        ]);
        ok(&out);
        let (w, h, img) = png_size(&png_path);
        assert_eq!((w, h), (3 * 96 + 2 * 2, 72), "{env}");
        // The first and the last frame of the strip differ.
        let row = |y: usize, x0: usize| &img[3 * (y * w as usize + x0)..][..3 * 96];
        assert!(
            (0..72).any(|y| row(y, 0) != row(y, 2 * (96 + 2))),
            "{env}: strip frames are identical"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_render_arguments_get_one_line_errors() {
    let dir = temp_dir("render-bad");
    let out_gif = dir.join("x.gif");
    let out_gif = out_gif.to_str().unwrap();
    for (args, want) in [
        (vec!["--env", "hopper", "--size", "320by240"], "--size"),
        (
            vec!["--env", "hopper", "--out", "x.mp4"],
            ".gif (animation) or .png",
        ),
        (
            vec!["--checkpoint", "/nonexistent/ckpt", "--out", out_gif],
            "not a checkpoint",
        ),
        (vec!["--run", dir.to_str().unwrap()], "not a run directory"),
        (vec!["--env", "hoppr", "--out", out_gif], "pendulum"),
        (vec!["--out", out_gif], "--env NAME"),
    ] {
        let out = render(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: one line: {err}");
        assert!(
            err.contains(want) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
    assert!(!Path::new(out_gif).exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_trained_runs_checkpoint_renders_its_best_actor() {
    let dir = temp_dir("render-run");
    let run_dir = dir.join("run");
    let sets = small_run(&["algo.actors=2", "run.total_env_steps=1000"]);
    let out = run(train(&run_dir, &sets));
    assert_success(&out, &run_dir);
    // --run: the run's env (pendulum) and its latest checkpoint's best actor, deterministic.
    let gif_path = dir.join("pendulum.gif");
    let args = [
        "--run",
        run_dir.to_str().unwrap(),
        "--steps",
        "30",
        "--size",
        "64x48",
        "--out",
        gif_path.to_str().unwrap(),
    ];
    let err = ok(&render(&args));
    assert!(
        err.contains("pendulum with actor") && err.contains("of 2"),
        "{err}"
    );
    let frames = gif_frames(&gif_path, 64, 48);
    assert_eq!(frames.len(), 31);
    assert_ne!(frames[0].0, frames[30].0);
    let again = std::fs::read(&gif_path).unwrap();
    ok(&render(&args));
    assert_eq!(
        std::fs::read(&gif_path).unwrap(),
        again,
        "same seed, same GIF"
    );
    // A checkpoint directory or its model.safetensors, a chosen actor.
    let ckpt = run_dir.join("checkpoints/final");
    let model = ckpt.join("model.safetensors");
    for (source, env) in [(&ckpt, None), (&model, Some("pendulum"))] {
        let mut a = vec![
            "--checkpoint",
            source.to_str().unwrap(),
            "--actor",
            "1",
            "--steps",
            "5",
            "--size",
            "32x24",
            "--out",
            gif_path.to_str().unwrap(),
        ];
        if let Some(e) = env {
            a.extend(["--env", e]);
        }
        let err = ok(&render(&a));
        assert!(err.contains("actor 1 of 2"), "{err}");
    }
    // The actor does not fit another env; a missing actor.
    for (extra, want) in [
        (vec!["--env", "hopper"], "pass the run's env"),
        (vec!["--actor", "7"], "2 actors"),
    ] {
        let mut a = vec![
            "--checkpoint",
            ckpt.to_str().unwrap(),
            "--out",
            gif_path.to_str().unwrap(),
        ];
        a.extend(extra);
        let out = render(&a);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(want), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
