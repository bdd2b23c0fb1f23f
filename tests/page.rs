//! The 3D page in headless Chromium (Debian's package): it loads from disk without console
//! messages, the canvas draws the figures, and moving the frame slider changes the picture.
//! Without Chromium the test skips with a notice, unless DIFFKFC_REQUIRE_CHROMIUM=1 (set by
//! .ci/run, which installs it) makes that a failure.

mod common;
use std::path::Path;
use std::process::{Command, Output};

use common::*;
use diffkfc_data::testing::fixtures;

fn headless(chromium: &Path, extra: &[&str], url: &str) -> Output {
    // A profile per call: tests run in parallel, and Chromium refuses a profile in use.
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let profile = std::env::temp_dir().join(format!("diffkfc-chromium-{}-{n}", std::process::id()));
    let out = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1280,800",
            "--virtual-time-budget=4000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(url)
        .output()
        .expect("run chromium");
    let _ = std::fs::remove_dir_all(&profile);
    out
}

/// RGB pixels of the view (the canvas's rows of the screenshot).
fn pixels(png_path: &Path) -> (usize, usize, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(png_path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    let ch = info.color_type.samples();
    let rgb: Vec<u8> =
        buf[..info.buffer_size()].chunks(ch).flat_map(|p| [p[0], p[1], p[2]]).collect();
    (info.width as usize, info.height as usize, rgb)
}

/// Chromium, a real clip and the text encoder, or None (after a notice) where one is missing.
fn needs() -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    let chromium = chromium()?;
    let src = fixtures::require("humanml3d/new_joint_vecs/012314.npy")?;
    have_text_encoder().then_some((chromium, src))
}

/// `samples` 100-frame walks of the reference model keyed at `frames` of `src`, into `out`.
fn sample_walk(src: &Path, frames: &str, samples: usize, out: &Path) {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let n = samples.to_string();
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--text",
        "a person walks forward.",
        "--from",
        s(src),
        "--frames",
        frames,
        "--length",
        "100",
        "--num-samples",
        &n,
        "--steps",
        "4",
        "--out",
        s(out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn page_draws_and_the_slider_moves_the_figures() {
    let Some((chromium, src)) = needs() else {
        return;
    };
    let d = scratch("page");
    let out = d.join("walk");
    sample_walk(&src, "0,40,80", 2, &out);
    let url = |frame: usize| format!("file://{}#frame={frame}", out.join("index.html").display());

    // A frame in the middle of the first sample's longest planted span, where its toe is drawn.
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    let spans = r["samples"][0]["foot_lock"]["spans"].as_array().unwrap().clone();
    let span = |s: &serde_json::Value| (s["start"].as_u64().unwrap(), s["end"].as_u64().unwrap());
    let (a, b) = spans.iter().map(span).max_by_key(|(a, b)| b - a).expect("a planted span");
    let mid = ((a + b) / 2) as usize;
    let dom = headless(&chromium, &["--dump-dom"], &url(mid));
    let (html, log) = (stdout(&dom), stderr(&dom));
    assert!(dom.status.success(), "{log}");
    let console: Vec<&str> = log.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:?}");
    // The page reports what it drew: the frame the slider set and the left limbs' pixels.
    let status =
        html.split("<output id=\"status\">").nth(1).and_then(|s| s.split('<').next()).unwrap_or("");
    eprintln!("page at #frame={mid}: {status}");
    assert!(status.starts_with(&format!("frame {mid};")), "{status}");
    let count = |what: &str| -> usize {
        let tail = status.split(what).nth(1).unwrap_or_else(|| panic!("{what}: {status}"));
        tail.trim().split(|c: char| !c.is_ascii_digit()).next().unwrap().parse().unwrap()
    };
    let drawn = count("left-limb pixels");
    assert!(drawn > 300, "figures cover {drawn} px");
    // The track fit's root path (dashed violet) and the planted toes (green discs) are drawn.
    assert!(count("root-path pixels") > 100, "{status}");
    assert!(count("planted-foot pixels") > 10, "{status}");
    for label in ["source", "sample_00", "sample_01", "sample_00.bvh"] {
        assert!(html.contains(label), "{label} missing from the page");
    }

    let shots: Vec<_> = [0usize, 70]
        .iter()
        .map(|&f| {
            let png = d.join(format!("frame{f}.png"));
            let o = headless(&chromium, &[&format!("--screenshot={}", png.display())], &url(f));
            assert!(o.status.success() && png.exists(), "{}", stderr(&o));
            pixels(&png)
        })
        .collect();
    let (w, h, a) = &shots[0];
    let b = &shots[1].2;
    // The view is the canvas below the title; count changed pixels in the rows it covers.
    let rows = (h / 6)..(h * 3 / 4);
    let changed = rows
        .clone()
        .flat_map(|y| (0..*w).map(move |x| (y * w + x) * 3))
        .filter(|&i| (0..3).any(|c| a[i + c].abs_diff(b[i + c]) > 40))
        .count();
    let blue = |p: &[u8]| {
        rows.clone()
            .flat_map(|y| (0..*w).map(move |x| (y * w + x) * 3))
            .filter(|&i| p[i + 2] > 150 && p[i] < 120)
            .count()
    };
    eprintln!("screenshots at frames 0 and 70: {changed} pixels differ in the view; left-limb blue pixels {} and {}", blue(a), blue(b));
    assert!(blue(a) > 300 && blue(b) > 300, "figures not drawn");
    assert!(changed > 500, "the slider did not move the figures ({changed} px changed)");
}

/// The comparison page of `render --page`: every image and link it names exists beside it,
/// Chromium loads it without console messages, its 3D view draws every folder's figure, and
/// the terminal gets the same numbers as a table.
#[test]
fn comparison_page_links_resolve_and_its_view_draws() {
    let Some((chromium, src)) = needs() else {
        return;
    };
    let d = scratch("compare");
    for (name, frames) in [("walk", "0,40,80"), ("still", "0")] {
        sample_walk(&src, frames, 1, &d.join(name));
    }
    let page = d.join("page/index.html");
    let o = diffkfc(&["render", "--page", s(&d.join("walk")), s(&d.join("still")), "-o", s(&page)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    assert!(table.lines().any(|l| l.starts_with("foot skating (source)")), "{table}");
    // The line naming the written page is as long as its path.
    let mut rows = table.lines().filter(|l| !l.contains(s(&page)));
    assert!(rows.all(|l| l.chars().count() <= 100), "wider than a terminal: {table}");
    assert!(table.contains("walk: ") && table.contains("0, 40, 80"), "{table}");
    let html = std::fs::read_to_string(&page).unwrap();
    let dir = page.parent().unwrap();
    let mut targets = 0;
    for attr in ["src='", "href='"] {
        for t in html.split(attr).skip(1).filter_map(|r| r.split('\'').next()) {
            assert!(dir.join(t).exists(), "{t} does not resolve from {}", page.display());
            targets += 1;
        }
    }
    // GIFs and folder pages of both folders, the view (twice), the sheet.
    assert!(targets >= 7, "{targets} links");
    let dom = headless(&chromium, &["--dump-dom"], &format!("file://{}", page.display()));
    let console: Vec<String> =
        stderr(&dom).lines().filter(|l| l.contains(":CONSOLE")).map(String::from).collect();
    assert!(dom.status.success() && console.is_empty(), "{console:?}");
    let view = headless(
        &chromium,
        &["--dump-dom"],
        &format!("file://{}#frame=40", dir.join("view.html").display()),
    );
    let html = stdout(&view);
    let status =
        html.split("<output id=\"status\">").nth(1).and_then(|s| s.split('<').next()).unwrap_or("");
    assert!(status.starts_with("frame 40;"), "{status}");
    for label in ["walk", "still"] {
        assert!(html.contains(label), "{label} missing from the view");
    }
}
