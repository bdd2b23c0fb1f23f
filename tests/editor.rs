//! The keyframe editor in a real browser: `diffkfc serve` and headless Chromium driven over
//! the DevTools protocol with real mouse input. The page loads and generates; a 196-frame
//! motion gets ten keys (the last added with the "add key" button); dragging that key's place
//! on the ground regenerates a motion that hits the moved key (pose and place within 1 cm),
//! the picture changes, and the time from the edit to the new motion drawn is reported. Then
//! the key is re-posed by dragging its wrist (IK keeps the arm's bones), the undo button brings
//! the old pose back, and the key is dragged along the timeline to another frame.

mod common;
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine as _;
use common::*;
use serde_json::{json, Value};
use tungstenite::{stream::MaybeTlsStream, Message, WebSocket};

/// A child process killed when dropped.
struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// One page of Chromium over the DevTools protocol.
struct Page {
    ws: WebSocket<MaybeTlsStream<TcpStream>>,
    session: String,
    next: u64,
}

impl Page {
    fn call(&mut self, method: &str, params: Value, session: bool) -> Value {
        self.next += 1;
        let mut msg = json!({"id": self.next, "method": method, "params": params});
        if session {
            msg["sessionId"] = json!(self.session);
        }
        self.ws.send(Message::Text(msg.to_string().into())).unwrap();
        loop {
            let Message::Text(t) = self.ws.read().unwrap() else { continue };
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["id"] == self.next {
                assert!(v.get("error").is_none(), "{method}: {}", v["error"]);
                return v["result"].clone();
            }
        }
    }

    /// The value of a JavaScript expression (promises awaited).
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expr, "returnByValue": true, "awaitPromise": true}),
            true,
        );
        assert!(r.get("exceptionDetails").is_none(), "{expr}: {}", r["exceptionDetails"]);
        r["result"]["value"].clone()
    }

    fn wait_for(&mut self, expr: &str, what: &str) {
        let t0 = Instant::now();
        while self.eval(expr) != json!(true) {
            assert!(t0.elapsed() < Duration::from_secs(60), "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Wait until the page's newest edit is generated and drawn.
    fn settle(&mut self) {
        let s = "diffkfcEditor.state";
        self.wait_for(&format!("typeof diffkfcEditor !== 'undefined' && !{s}.inFlight && !{s}.dirty && {s}.drawn === {s}.generation && {s}.generation > 0"), "the motion");
    }

    fn mouse(&mut self, kind: &str, x: f64, y: f64) {
        let p = json!({"type": kind, "x": x, "y": y, "button": "left", "buttons": if kind == "mouseReleased" { 0 } else { 1 }, "clickCount": 1});
        self.call("Input.dispatchMouseEvent", p, true);
    }

    fn click(&mut self, x: f64, y: f64) {
        self.mouse("mousePressed", x, y);
        self.mouse("mouseReleased", x, y);
    }

    /// Centre of an element, in page pixels.
    fn centre(&mut self, id: &str) -> (f64, f64) {
        let r = self.eval(&format!("(() => {{ const r = document.getElementById('{id}').getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2]; }})()"));
        (r[0].as_f64().unwrap(), r[1].as_f64().unwrap())
    }

    /// Where `diffkfcEditor.handle(args)` is drawn, in page pixels (the view's offset added).
    fn handle(&mut self, args: &str) -> (f64, f64) {
        let h = self.eval(&format!("(() => {{ const h = diffkfcEditor.handle({args}), r = document.getElementById('view').getBoundingClientRect(); return [h[0] + r.left, h[1] + r.top]; }})()"));
        (h[0].as_f64().unwrap(), h[1].as_f64().unwrap())
    }

    fn screenshot(&mut self) -> Vec<u8> {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}), true);
        base64::engine::general_purpose::STANDARD.decode(r["data"].as_str().unwrap()).unwrap()
    }
}

fn open(chromium: &std::path::Path, url: &str, profile: &std::path::Path) -> (Proc, Page) {
    let mut c = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--remote-debugging-port=0",
            "--window-size=1280,1000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("about:blank")
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .expect("start chromium");
    let line = line_with(c.stderr.take().unwrap(), "DevTools listening on");
    let ws_url = line.split("listening on ").nth(1).unwrap().trim().to_string();
    let (ws, _) = tungstenite::connect(ws_url).expect("connect to chromium");
    let mut page = Page { ws, session: String::new(), next: 0 };
    let target = page.call("Target.createTarget", json!({"url": url}), false)["targetId"].clone();
    let attached =
        page.call("Target.attachToTarget", json!({"targetId": target, "flatten": true}), false);
    page.session = attached["sessionId"].as_str().unwrap().to_string();
    (Proc(c), page)
}

#[test]
fn drag_a_key_and_the_motion_follows() {
    let Some(chromium) = chromium() else { return };
    if !have_text_encoder() {
        return;
    }
    // The tiny model by default; DIFFKFC_EDITOR_MODEL=models/mid-synth times the reference model.
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(std::env::var("DIFFKFC_EDITOR_MODEL").unwrap_or_else(|_| "models/tiny-synth".into()));
    let mut server = Command::new(env!("CARGO_BIN_EXE_diffkfc"))
        .args(["serve", "--checkpoint", s(&model), "--port", "0"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start diffkfc serve");
    let line = line_with(server.stdout.take().unwrap(), "diffkfc editor: http://");
    let _server = Proc(server);
    let url = line.split_whitespace().find(|w| w.starts_with("http://")).unwrap().to_string();
    let profile = scratch("editor-chromium");
    let (browser, mut page) = open(&chromium, &url, &profile);
    page.settle();
    // A 196-frame motion with nine keys taken from the generated motion.
    page.eval("(() => { const l = document.getElementById('length'); l.value = 196; l.dispatchEvent(new Event('change')); })()");
    page.settle();
    for f in [0, 20, 40, 60, 80, 100, 120, 140, 170] {
        page.eval(&format!("diffkfcEditor.state.frame = {f}; diffkfcEditor.addKey('motion')"));
        page.settle();
    }
    // The tenth with the mouse: seek on the timeline, then the button.
    let tl = page.eval("(() => { const r = document.getElementById('timeline').getBoundingClientRect(); return [r.left, r.top + r.height / 2, r.width]; })()");
    let (left, mid, w) =
        (tl[0].as_f64().unwrap(), tl[1].as_f64().unwrap(), tl[2].as_f64().unwrap());
    page.click(left + 8.0 + (w - 16.0) * 190.0 / 195.0, mid);
    assert_eq!(page.eval("diffkfcEditor.state.frame"), json!(190));
    let (bx, by) = page.centre("add-key");
    page.click(bx, by);
    page.settle();
    assert_eq!(page.eval("diffkfcEditor.state.keys.length"), json!(10));
    let before = page.screenshot();
    // Drag the new key's place 0.5 m or so across the ground, several times.
    let mut latencies = Vec::new();
    let mut server_ms = Vec::new();
    for (dx, dy) in [(90.0, 30.0), (-60.0, 40.0), (70.0, -50.0), (-40.0, -30.0), (50.0, 20.0)] {
        let key = page.eval("diffkfcEditor.state.selected");
        let place0 = page.eval(&format!("diffkfcEditor.state.keys[{key}].place"));
        let at = page.handle(&format!("'place', {key}"));
        let generation = page.eval("diffkfcEditor.state.generation").as_u64().unwrap();
        drag(&mut page, at, (dx, dy));
        page.wait_for(&format!("diffkfcEditor.state.generation > {generation}"), "a new motion");
        page.settle();
        let st = page.eval(&format!("(() => {{ const s = diffkfcEditor.state, k = s.keys[{key}]; return {{place: k.place, frame: k.frame, reply: s.motion.keys.find((r) => r.frame === k.frame), latency: s.latencyMs, server: s.serverMs}}; }})()"));
        let p1 = &st["place"];
        let moved = (p1[0].as_f64().unwrap() - place0[0].as_f64().unwrap())
            .hypot(p1[1].as_f64().unwrap() - place0[1].as_f64().unwrap());
        assert!(moved > 0.1, "the drag moved the key's place by only {moved} m: {st}");
        let (pose, place) = (
            st["reply"]["pose_err_m"].as_f64().unwrap(),
            st["reply"]["place_err_m"].as_f64().unwrap(),
        );
        assert!(
            pose < 0.01 && place < 0.01,
            "the moved key is missed: pose {pose} m, place {place} m ({st})"
        );
        latencies.push(st["latency"].as_f64().unwrap());
        server_ms.push(st["server"].as_f64().unwrap());
    }
    repose_undo_and_retime(&mut page, (left, mid, w));
    let after = page.screenshot();
    // The README's picture: DIFFKFC_EDITOR_SCREENSHOT=docs/editor.png cargo test --test editor
    if let Some(p) = std::env::var_os("DIFFKFC_EDITOR_SCREENSHOT") {
        std::fs::write(p, &after).unwrap();
    }
    let changed = before.len() != after.len() || before != after;
    assert!(changed, "the picture did not change");
    latencies.sort_by(f64::total_cmp);
    server_ms.sort_by(f64::total_cmp);
    println!(
        "editor: 196 frames, 10 keys; edit to new motion drawn: median {:.0} ms (all {:?}); server median {:.0} ms",
        latencies[2],
        latencies.iter().map(|v| v.round()).collect::<Vec<_>>(),
        server_ms[2]
    );
    // The target is 0.5 s on a quiet 2-core machine; the bound here leaves room for a loaded CI.
    assert!(latencies[2] < 3000.0, "edit to picture took {} ms", latencies[2]);
    // Chromium writes to its profile as it exits: stopped first, its folder then goes with it.
    drop(page);
    drop(browser);
    drop(profile);
}

/// Drag from (x, y) by (dx, dy) in eight moves.
fn drag(page: &mut Page, (x, y): (f64, f64), (dx, dy): (f64, f64)) {
    page.mouse("mousePressed", x, y);
    for k in 1..=8 {
        let t = k as f64 / 8.0;
        page.mouse("mouseMoved", x + dx * t, y + dy * t);
    }
    page.mouse("mouseReleased", x + dx, y + dy);
}

/// The selected key's pose and frame, and how the last motion hit it.
fn selected(page: &mut Page) -> Value {
    page.eval("(() => { const s = diffkfcEditor.state, k = s.keys[s.selected]; return {pose: k.pose, frame: k.frame, generation: s.generation, reply: s.motion.keys.find((r) => r.frame === k.frame)}; })()")
}

fn dist(a: &Value, b: &Value) -> f64 {
    (0..3).map(|i| (a[i].as_f64().unwrap() - b[i].as_f64().unwrap()).powi(2)).sum::<f64>().sqrt()
}

fn repose_undo_and_retime(page: &mut Page, (left, mid, w): (f64, f64, f64)) {
    let (shoulder, elbow, wrist) = (16, 18, 20);
    let before = selected(page);
    let key = page.eval("diffkfcEditor.state.selected");
    let at = page.handle(&format!("'joint', {key}, {wrist}"));
    drag(page, at, (15.0, -60.0));
    page.wait_for(
        &format!("diffkfcEditor.state.generation > {}", before["generation"]),
        "the re-posed motion",
    );
    page.settle();
    let after = selected(page);
    let (p0, p1) = (&before["pose"], &after["pose"]);
    assert!(
        dist(&p0[wrist], &p1[wrist]) > 0.03,
        "the wrist did not move: {}",
        dist(&p0[wrist], &p1[wrist])
    );
    for (a, b) in [(shoulder, elbow), (elbow, wrist)] {
        let (l0, l1) = (dist(&p0[a], &p0[b]), dist(&p1[a], &p1[b]));
        assert!((l0 - l1).abs() < 1e-6, "bone {a}-{b} changed length: {l0} -> {l1}");
    }
    let e = after["reply"]["pose_err_m"].as_f64().unwrap();
    assert!(e < 0.01, "the re-posed key is missed by {e} m");
    let (ux, uy) = page.centre("undo");
    page.click(ux, uy);
    page.wait_for(
        &format!("diffkfcEditor.state.generation > {}", after["generation"]),
        "the undone motion",
    );
    page.settle();
    let undone = selected(page);
    assert!(dist(&undone["pose"][wrist], &p0[wrist]) < 1e-9, "undo did not restore the pose");
    // Along the timeline: from its frame to 10 frames earlier (the next key is 20 frames away).
    let f0 = undone["frame"].as_f64().unwrap();
    let x = |f: f64| left + 8.0 + (w - 16.0) * f / 195.0;
    drag(page, (x(f0), mid), (x(f0 - 10.0) - x(f0), 0.0));
    page.wait_for(
        &format!("diffkfcEditor.state.generation > {}", undone["generation"]),
        "the retimed motion",
    );
    page.settle();
    let moved = selected(page);
    let f1 = moved["frame"].as_f64().unwrap();
    assert!(
        (f1 - (f0 - 10.0)).abs() <= 1.0,
        "the key went from frame {f0} to {f1}, not {}",
        f0 - 10.0
    );
    let (pose, place) = (
        moved["reply"]["pose_err_m"].as_f64().unwrap(),
        moved["reply"]["place_err_m"].as_f64().unwrap(),
    );
    assert!(
        pose < 0.01 && place < 0.01,
        "the retimed key is missed: pose {pose} m, place {place} m"
    );
}

/// `serve`'s own bad input: a queue out of range and a checkpoint that is not there are one-line
/// errors naming the flag, and the command exits instead of serving.
#[test]
fn serve_refuses_bad_flags() {
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let o = diffkfc(&["serve", "--checkpoint", s(&model), "--port", "0", "--queue", "0"]);
    assert_one_line_error(&o, &["--queue", "0", "1 to 1024"]);
    let d = scratch("serve-bad");
    let missing = d.join("no-such-model");
    let o = diffkfc(&["serve", "--checkpoint", s(&missing), "--port", "0"]);
    assert_one_line_error(&o, &["--checkpoint", "no-such-model"]);
}
