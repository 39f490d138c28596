//! `softbody render`: PNG directories and GIFs from scenes and from JSON Lines frames, the same
//! pixels both ways, and the exit statuses of bad input and unwritable outputs.

mod common;

use std::path::Path;

use common::*;

/// A short scene: a 3×3×3 cube dropped on the ground, 6 frames (0.05 s at 100 frames/s).
fn cube() -> Cube {
    Cube::default()
}

/// Decodes a PNG file: (width, height, RGB bytes).
fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// Pictures small enough to draw quickly, and no progress or summary.
const SMALL: [&str; 5] = ["--width", "32", "--height", "24", "-q"];

fn pngs(dir: &Path) -> Vec<String> {
    entries(dir)
        .into_iter()
        .filter(|n| n.ends_with(".png"))
        .collect()
}

#[test]
fn a_scene_renders_one_png_per_frame_showing_the_body() {
    let sb = Sandbox::new();
    let scene = sb.write("cube.toml", &cube().toml());
    let out = sb.path().join("pictures");
    let o = sb.run(&[
        "render".as_ref(),
        scene.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--width".as_ref(),
        "160".as_ref(),
        "--height".as_ref(),
        "120".as_ref(),
    ]);
    o.expect_status(EXIT_OK);
    let frames = frame_schedule(0.001, 0.05, 100.0).len();
    assert_eq!(frames, 6);
    let names = pngs(&out);
    let expected: Vec<String> = (0..frames).map(|k| format!("frame_{k:06}.png")).collect();
    assert_eq!(names, expected);
    // Nothing else is left beside it (no temporary directory).
    assert_eq!(entries(sb.path()), ["cube.toml", "pictures"]);
    // The summary line names the frames and the destination.
    assert!(
        o.stderr.contains("6 frames of 160×120") && o.stderr.contains("pictures"),
        "{}",
        o.stderr
    );

    let (w, h, rgb) = read_png(&out.join("frame_000000.png"));
    assert_eq!((w, h), (160, 120));
    // The automatic camera looks at the middle of what is drawn: the cube (orange, its red
    // channel well above its blue one) covers the centre pixel; the top-left corner is sky
    // (blue above red).
    let px = |x: u32, y: u32| {
        let at = 3 * (y * w + x) as usize;
        [rgb[at], rgb[at + 1], rgb[at + 2]]
    };
    let [r, _, b] = px(80, 60);
    assert!(r > b + 60, "centre {:?}", px(80, 60));
    let [r, _, b] = px(0, 0);
    assert!(b > r + 40, "corner {:?}", px(0, 0));
    // The body moves: the last frame differs from the first.
    assert_ne!(read_png(&out.join("frame_000005.png")).2, rgb);
}

#[test]
fn a_gif_has_every_frame_and_jsonl_gives_the_same_pixels() {
    let sb = Sandbox::new();
    let scene = sb.write("cube.toml", &cube().toml());
    let frames = sb.path().join("cube.jsonl");
    sb.run(&[
        "run".as_ref(),
        scene.as_os_str(),
        "--out".as_ref(),
        frames.as_os_str(),
        "-q".as_ref(),
    ])
    .expect_status(EXIT_OK);
    let common_args = ["--width", "96", "--height", "64", "--springs", "-q"];
    let gif = sb.path().join("a.gif");
    let from_scene = sb.path().join("from_scene");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "render".as_ref(),
        scene.as_os_str(),
        "--out".as_ref(),
        gif.as_os_str(),
        "--out".as_ref(),
        from_scene.as_os_str(),
    ];
    args.extend(common_args.iter().map(std::ffi::OsStr::new));
    let o = sb.run(&args);
    o.expect_status(EXIT_OK);
    assert!(o.stderr.is_empty(), "--quiet prints nothing: {}", o.stderr);

    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options
        .read_info(std::fs::File::open(&gif).unwrap())
        .unwrap();
    assert_eq!((decoder.width(), decoder.height()), (96, 64));
    let mut count = 0;
    while let Some(frame) = decoder.read_next_frame().unwrap() {
        // 100 frames/s: one hundredth of a second is below what viewers show, so 2.
        assert_eq!(frame.delay, 2);
        count += 1;
    }
    assert_eq!(count, 6);

    let from_jsonl = sb.path().join("from_jsonl");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "render".as_ref(),
        frames.as_os_str(),
        "--out".as_ref(),
        from_jsonl.as_os_str(),
    ];
    args.extend(common_args.iter().map(std::ffi::OsStr::new));
    sb.run(&args).expect_status(EXIT_OK);
    assert_eq!(pngs(&from_jsonl).len(), 6);
    for name in pngs(&from_scene) {
        assert_eq!(
            read_png(&from_scene.join(&name)),
            read_png(&from_jsonl.join(&name)),
            "{name}"
        );
    }
    // The same command twice: the same bytes.
    let again = sb.path().join("again");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "render".as_ref(),
        frames.as_os_str(),
        "--out".as_ref(),
        again.as_os_str(),
    ];
    args.extend(common_args.iter().map(std::ffi::OsStr::new));
    sb.run(&args).expect_status(EXIT_OK);
    for name in pngs(&again) {
        assert_eq!(
            std::fs::read(again.join(&name)).unwrap(),
            std::fs::read(from_jsonl.join(&name)).unwrap()
        );
    }
}

#[test]
fn a_given_camera_and_an_existing_directory() {
    let sb = Sandbox::new();
    let scene = sb.write("cube.toml", &cube().toml());
    let out = sb.mkdir("pictures");
    // An earlier, longer render's frame and an unrelated file.
    std::fs::write(out.join("frame_000042.png"), b"old").unwrap();
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let o = sb.run(&[
        "render",
        "cube.toml",
        "--out",
        "pictures",
        "--width",
        "64",
        "--height",
        "48",
        "--camera-from",
        "0,1,-4",
        "--camera-to",
        "0,1,0",
        "-q",
    ]);
    o.expect_status(EXIT_OK);
    let _ = scene;
    let mut names = entries(&out);
    names.retain(|n| n != "notes.txt");
    assert_eq!(names.len(), 6, "{names:?}");
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"mine");
    // Looking along +z at the cube's centre from 4 m: the cube is in the middle.
    let (_, _, rgb) = read_png(&out.join("frame_000000.png"));
    let at = 3 * (24 * 64 + 32);
    assert!(rgb[at] > rgb[at + 2] + 60, "{:?}", &rgb[at..at + 3]);
}

#[test]
fn an_unstable_scene_keeps_the_frames_before_it() {
    let sb = Sandbox::new();
    sb.write("unstable.toml", &Cube::unstable().toml());
    let o = sb.run(&[
        "render",
        "unstable.toml",
        "--out",
        "p",
        "--width",
        "32",
        "--height",
        "24",
        "-q",
    ]);
    o.expect_status(EXIT_UNSTABLE);
    assert!(o.stderr.contains("unstable"), "{}", o.stderr);
    let n = pngs(&sb.path().join("p")).len();
    let all = frame_schedule(0.01, 2.0, 50.0).len();
    assert!(n >= 1 && n < all, "{n} of {all}");
}

#[test]
fn bad_input_is_refused_with_status_2() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    sb.write("notes.txt", "hello");
    sb.write("bad.jsonl", "{\"softbody_frames\":1,\"particles\":27,\"frame_rate\":100.0,\"frames\":6,\"scene\":\"cube.toml\"}\n{\"frame\":0,\"positions\":[[0.0,");
    sb.write("bad.toml", "[simulation]\ndt = -1.0\n");
    let cases: &[&[&str]] = &[
        &["render", "missing.toml"],
        &["render", "missing.jsonl"],
        &["render", "notes.txt"],
        &["render", "bad.jsonl"],
        &["render", "bad.toml"],
        &["render", "cube.toml", "--width", "0"],
        &["render", "cube.toml", "--height", "8193"],
        &["render", "cube.toml", "--camera-from", "1,2"],
        &["render", "cube.toml", "--camera-from", "1,2,x"],
        &[
            "render",
            "cube.toml",
            "--camera-from",
            "0,1,0",
            "--camera-to",
            "0,1,0",
        ],
        &[
            "render",
            "cube.toml",
            "--camera-from",
            "0,5,0",
            "--camera-to",
            "0,1,0",
        ],
        &["render", "cube.toml", "--strain-range", "0"],
    ];
    for args in cases {
        let o = sb.run(args);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(o.stderr.contains("error"), "{args:?}: {}", o.stderr);
    }
    // Nothing was written (the default destination's parent may have been made, empty).
    assert_eq!(entries(&sb.path().join("out")), Vec::<String>::new());

    // Frames whose scene file is gone, and frames with a bad line: status 2, with the line.
    let scene = sb.write("gone/cube.toml", &cube().toml());
    sb.run(&["run", "gone/cube.toml", "--out", "gone.jsonl", "-q"])
        .expect_status(EXIT_OK);
    std::fs::remove_file(&scene).unwrap();
    let o = sb.run(&["render", "gone.jsonl", "--out", "g"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(o.stderr.contains("cube.toml"), "{}", o.stderr);

    sb.run(&["run", "cube.toml", "--out", "ok.jsonl", "-q"])
        .expect_status(EXIT_OK);
    let text = std::fs::read_to_string(sb.path().join("ok.jsonl")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[3] = "{\"frame\": 2, \"positions\": oops}";
    sb.write("broken.jsonl", &(lines.join("\n") + "\n"));
    let o = sb.run(&["render", "broken.jsonl", "--out", "b", "-q"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(o.stderr.contains("broken.jsonl:4"), "{}", o.stderr);
    // The frames before the bad line are not left behind.
    assert!(!sb.path().join("b").exists());
    assert_eq!(
        entries(sb.path())
            .iter()
            .filter(|n| n.starts_with(".softbody-"))
            .count(),
        0
    );
}

/// Frames from a JSON Lines file that does not start at frame 0 (trimmed by hand): drawing it
/// twice into one directory keeps every picture (the second render replaces the first's), and a
/// duplicated or reordered line, whose picture would replace another, is refused with its line.
#[test]
fn trimmed_frames_render_twice_and_out_of_order_frames_are_refused() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    sb.run(&["run", "cube.toml", "--out", "all.jsonl", "-q"])
        .expect_status(EXIT_OK);
    let text = std::fs::read_to_string(sb.path().join("all.jsonl")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    // The header, then frames 2, 3, 4, 5.
    let trimmed: Vec<&str> = std::iter::once(lines[0])
        .chain(lines[3..].iter().copied())
        .collect();
    sb.write("trimmed.jsonl", &(trimmed.join("\n") + "\n"));
    let expected = [
        "frame_000002.png",
        "frame_000003.png",
        "frame_000004.png",
        "frame_000005.png",
    ];
    for _ in 0..2 {
        sb.run(&[&["render", "trimmed.jsonl", "--out", "p"][..], &SMALL].concat())
            .expect_status(EXIT_OK);
        assert_eq!(pngs(&sb.path().join("p")), expected);
    }
    let mut duplicated = lines.clone();
    duplicated.insert(3, lines[2]);
    sb.write("duplicated.jsonl", &(duplicated.join("\n") + "\n"));
    let o = sb.run(&["render", "duplicated.jsonl", "--out", "d", "-q"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr
            .contains("duplicated.jsonl:4: frame 1 after frame 1"),
        "{}",
        o.stderr
    );
    assert!(!sb.path().join("d").exists());
}

/// Frames whose scene moved render with `--scene` naming its new place (and without it the
/// error says so); the overrides of a simulation do not apply to frames.
#[test]
fn frames_whose_scene_moved_render_with_scene() {
    let sb = Sandbox::new();
    sb.write("old/cube.toml", &cube().toml());
    sb.run(&["run", "old/cube.toml", "--out", "f.jsonl", "-q"])
        .expect_status(EXIT_OK);
    std::fs::rename(sb.path().join("old"), sb.path().join("new")).unwrap();
    let o = sb.run(&["render", "f.jsonl", "--out", "p", "-q"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(o.stderr.contains("--scene"), "{}", o.stderr);
    let args = [
        "render",
        "f.jsonl",
        "--scene",
        "new/cube.toml",
        "--out",
        "p",
    ];
    sb.run(&[&args[..], &SMALL].concat()).expect_status(EXIT_OK);
    assert_eq!(pngs(&sb.path().join("p")).len(), 6);
    for extra in [
        &["--dt", "1/2000"][..],
        &["--integrator", "rk4"],
        &["--backend", "gpu"],
    ] {
        let o = sb.run(&[&args[..], extra].concat());
        o.expect_status(EXIT_BAD_INPUT);
        assert!(
            o.stderr.contains("apply to a scene"),
            "{extra:?}: {}",
            o.stderr
        );
    }
    let o = sb.run(&["render", "new/cube.toml", "--scene", "new/cube.toml"]);
    o.expect_status(EXIT_BAD_INPUT);
}

/// The default destinations of `render` and `run --format ply` differ (out/NAME-pictures/ and
/// out/NAME-ply/), and overrides name their own: no command replaces another's output.
#[test]
fn default_destinations_do_not_collide() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    sb.run(&[&["render", "cube.toml"][..], &SMALL].concat())
        .expect_status(EXIT_OK);
    sb.run(&[&["render", "cube.toml", "--fps", "50"][..], &SMALL].concat())
        .expect_status(EXIT_OK);
    sb.run(&["run", "cube.toml", "--format", "ply", "-q"])
        .expect_status(EXIT_OK);
    let out = sb.path().join("out");
    assert_eq!(
        entries(&out),
        ["cube-50fps-pictures", "cube-pictures", "cube-ply"]
    );
    assert_eq!(pngs(&out.join("cube-pictures")).len(), 6);
    assert_eq!(pngs(&out.join("cube-50fps-pictures")).len(), 3);
}

#[test]
fn an_unwritable_destination_is_status_1() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    sb.write("file", "not a directory");
    for out in ["/proc/nope/pictures", "/proc/nope.gif", "file"] {
        let o = sb.run(&["render", "cube.toml", "--out", out, "-q"]);
        o.expect_status(EXIT_OUTPUT);
        assert!(o.stderr.contains("error"), "{out}: {}", o.stderr);
    }
}

#[test]
fn follow_keeps_the_body_in_the_middle() {
    let sb = Sandbox::new();
    let moving = Cube {
        velocity: [3.0, 0.0, 0.0],
        duration: 0.3,
        frame_rate: 20.0,
        ..Cube::default()
    };
    sb.write("moving.toml", &moving.toml());
    sb.run(&[
        "render",
        "moving.toml",
        "--out",
        "p",
        "--width",
        "64",
        "--height",
        "48",
        "--follow",
        "-q",
    ])
    .expect_status(EXIT_OK);
    let names = pngs(&sb.path().join("p"));
    assert_eq!(names.len(), frame_schedule(0.001, 0.3, 20.0).len());
    // The camera looks at the centroid in every frame: the centre pixel is the orange body
    // in the first frame and in the last, 0.9 m further along x.
    for name in [names.first().unwrap(), names.last().unwrap()] {
        let (w, _, rgb) = read_png(&sb.path().join("p").join(name));
        let at = 3 * (24 * w + 32) as usize;
        assert!(rgb[at] > rgb[at + 2] + 60, "{name}: {:?}", &rgb[at..at + 3]);
    }
}

/// `--out` with an extension `render` does not write (a video, a single picture) is refused
/// before anything runs, naming what it writes; a name without one is a directory of PNGs.
#[test]
fn an_extension_render_does_not_write_is_refused() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    for out in ["x.mp4", "x.png", "movie.WEBM"] {
        let o = sb.run(&[&["render", "cube.toml", "--out", out][..], &SMALL].concat());
        o.expect_status(EXIT_BAD_INPUT);
        assert!(
            o.stderr.contains(out) && o.stderr.contains(".gif") && o.stderr.contains("PNG"),
            "{out}: {}",
            o.stderr
        );
    }
    assert_eq!(entries(sb.path()), ["cube.toml"]);
    // An existing directory is one whatever its name.
    sb.mkdir("take.v2");
    sb.run(&[&["render", "cube.toml", "--out", "take.v2"][..], &SMALL].concat())
        .expect_status(EXIT_OK);
    assert_eq!(pngs(&sb.path().join("take.v2")).len(), 6);
}

/// `--every K` draws the frames whose number is a multiple of K, from a scene and from saved
/// frames alike, and the GIF keeps the simulated time (K frame intervals a picture).
#[test]
fn every_kth_frame_is_drawn() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    sb.run(&["run", "cube.toml", "--out", "all.jsonl", "-q"])
        .expect_status(EXIT_OK);
    // Frames 0 to 5 at 100 frames/s.
    assert_eq!(frame_schedule(0.001, 0.05, 100.0).len(), 6);
    for input in ["all.jsonl", "cube.toml"] {
        let dir = format!("every-{}", input.replace('.', "-"));
        let o = sb.run(
            &[
                &[
                    "render", input, "--every", "2", "--out", &dir, "--out", "e.gif",
                ][..],
                &SMALL,
            ]
            .concat(),
        );
        o.expect_status(EXIT_OK);
        assert_eq!(
            pngs(&sb.path().join(&dir)),
            ["frame_000000.png", "frame_000002.png", "frame_000004.png"],
            "{input}"
        );
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options
            .read_info(std::fs::File::open(sb.path().join("e.gif")).unwrap())
            .unwrap();
        let mut delays = Vec::new();
        while let Some(frame) = decoder.read_next_frame().unwrap() {
            delays.push(frame.delay);
        }
        // Two hundredths of a second a picture: the first k end at round(100·2k/100).
        assert_eq!(delays, [2, 2, 2], "{input}");
    }
    // From frame 3 on (a trimmed file), every third: 3 only, of 3, 4, 5.
    let text = std::fs::read_to_string(sb.path().join("all.jsonl")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let trimmed: Vec<&str> = std::iter::once(lines[0])
        .chain(lines[4..].iter().copied())
        .collect();
    sb.write("trimmed.jsonl", &(trimmed.join("\n") + "\n"));
    sb.run(
        &[
            &["render", "trimmed.jsonl", "--every", "3", "--out", "t"][..],
            &SMALL,
        ]
        .concat(),
    )
    .expect_status(EXIT_OK);
    assert_eq!(pngs(&sb.path().join("t")), ["frame_000003.png"]);
    let o = sb.run(&["render", "cube.toml", "--every", "0"]);
    o.expect_status(EXIT_BAD_INPUT);
}

/// `--label` writes the frame's time in the top-left corner: the pixels it changes are all of
/// the label's colour, inside the box of its ten glyphs (5 × 7, one column apart, two pixels
/// from the edges at 120 rows), and they change from `t = 0.00 s` to `t = 0.05 s`.
#[test]
fn label_draws_the_time_in_the_corner() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &cube().toml());
    let size = ["--width", "160", "--height", "120", "-q"];
    for (out, label) in [("plain", false), ("labelled", true)] {
        let mut args = vec!["render", "cube.toml", "--out", out];
        args.extend(size);
        if label {
            args.push("--label");
        }
        sb.run(&args).expect_status(EXIT_OK);
    }
    let changed = |frame: &str| -> Vec<(u32, u32)> {
        let (w, h, plain) = read_png(&sb.path().join("plain").join(frame));
        let (_, _, labelled) = read_png(&sb.path().join("labelled").join(frame));
        let mut at = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let i = 3 * (y * w + x) as usize;
                if plain[i..i + 3] != labelled[i..i + 3] {
                    assert_eq!(labelled[i..i + 3], [20, 20, 20], "{frame} ({x}, {y})");
                    at.push((x, y));
                }
            }
        }
        at
    };
    let (first, last) = (changed("frame_000000.png"), changed("frame_000005.png"));
    // "t = 0.00 s": ten glyphs of 6 columns less the last space, from (2, 2).
    let (right, bottom) = (2 + 10 * 6 - 1, 2 + 7);
    for (x, y) in first.iter().chain(&last) {
        assert!(
            (2..right).contains(x) && (2..bottom).contains(y),
            "({x}, {y})"
        );
    }
    // At least the "t" and "=" (6 + 10 font pixels) and four digits are drawn.
    assert!(
        first.len() > 16 && last.len() > 16,
        "{} {}",
        first.len(),
        last.len()
    );
    assert_ne!(first, last, "the time changes");
}
