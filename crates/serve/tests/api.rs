//! The editor's JSON API against the reference model: keys are hit, every bad request gets a
//! 4xx with a one-line message (never a panic or a 5xx), a full queue gets 503, and exported
//! files read back.

mod common;
use common::*;
use serde_json::json;

/// Ten keyed places and headings along a walk of 196 frames, the first at the origin.
fn walk_keys() -> serde_json::Value {
    let keys: Vec<_> = (0..10)
        .map(|i| {
            let f = if i == 9 { 195 } else { i * 21 };
            json!({"frame": f, "root": [0.1 * (i as f64).sin(), 0.9, 1.1 * f as f64 / 20.0], "heading": 5.0 * i as f64})
        })
        .collect();
    json!({"length": 196, "keyframes": keys})
}

#[test]
fn keys_with_places_and_poses_are_hit() {
    let Some(srv) = server(4) else { return };
    let r = post(
        srv.addr,
        "/api/sample",
        &json!({"text": "a person walks forward.", "keyframes": walk_keys()}),
    );
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let m = r.json();
    assert_eq!(m["length"], 196);
    assert_eq!(m["joints"].as_array().unwrap().len(), 196 * 22 * 3);
    for k in m["keys"].as_array().unwrap() {
        let e = k["place_err_m"].as_f64().unwrap();
        assert!(e < 0.01, "key at frame {} missed its place by {e} m", k["frame"]);
        assert!(k["heading_err_deg"].as_f64().unwrap() < 0.5);
    }
    // Poses, places and headings picked from a generated motion, then asked for again at other
    // frames: every key is hit.
    let s = post(
        srv.addr,
        "/api/suggest",
        &json!({"request": {"text": "a person jumps.", "length": 100}, "count": 4}),
    );
    assert_eq!(s.status, 200, "{}", String::from_utf8_lossy(&s.body));
    let mut keys = s.json();
    assert_eq!(keys["keyframes"].as_array().unwrap().len(), 4);
    keys["length"] = json!(120);
    let r = post(
        srv.addr,
        "/api/sample",
        &json!({"text": "a person walks and jumps.", "keyframes": keys, "seed": 3}),
    );
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let m = r.json();
    for k in m["keys"].as_array().unwrap() {
        let (p, q) = (k["pose_err_m"].as_f64().unwrap(), k["place_err_m"].as_f64().unwrap());
        assert!(p < 0.01 && q < 0.01, "key {k}: pose {p} m, place {q} m");
    }
    assert!(m["metrics"]["k_err_m"].as_f64().unwrap() < 0.01);
    srv.stop().unwrap();
}

/// A request (method, path, headers, body) and the status and word of its answer.
type Case<'a> = (&'a str, &'a str, Vec<(&'a str, &'a str)>, String, u16, &'a str);

/// Every refused request: its status and a word of its message; the body is one line of JSON.
#[test]
fn bad_requests_get_4xx_and_one_line() {
    let Some(srv) = server(4) else { return };
    let a = srv.addr;
    let ok = json!({"text": "a person walks.", "length": 40});
    let with = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v = ok.clone();
        f(&mut v);
        v.to_string()
    };
    let key = |k: serde_json::Value| with(&|v| v["keyframes"] = json!({"keyframes": [k.clone()]}));
    let big = "x".repeat(3 << 20);
    let long = "a ".repeat(1500);
    let cases: Vec<Case> = vec![
        ("POST", "/api/sample", vec![("Host", "evil.example:7860")], ok.to_string(), 403, "Host"),
        ("GET", "/", vec![("Host", "attacker.test")], String::new(), 403, "Host"),
        (
            "POST",
            "/api/sample",
            vec![("Origin", "http://evil.example")],
            ok.to_string(),
            403,
            "Origin",
        ),
        (
            "POST",
            "/api/sample",
            vec![("Content-Type", "text/plain")],
            ok.to_string(),
            415,
            "application/json",
        ),
        (
            "POST",
            "/api/sample",
            vec![("Content-Type", "application/x-www-form-urlencoded")],
            "text=x".into(),
            415,
            "Content-Type",
        ),
        ("POST", "/api/sample", vec![], r#"{"text": "#.into(), 400, "request body"),
        ("POST", "/api/sample", vec![], r#"{"text": "a", "seed": NaN}"#.into(), 400, "seed"),
        (
            "POST",
            "/api/sample",
            vec![],
            r#"{"text": "a", "kf_guidance": 1e999}"#.into(),
            400,
            "kf_guidance",
        ),
        ("POST", "/api/sample", vec![], r#"{"txt": "a"}"#.into(), 400, "did you mean `text`"),
        ("POST", "/api/sample", vec![], r#"{"text": "a", "fit": "bogus"}"#.into(), 400, "fit"),
        (
            "POST",
            "/api/sample",
            vec![],
            vec![0xff, 0xfe].into_iter().map(char::from).collect(),
            400,
            "request body",
        ),
        ("POST", "/api/sample", vec![], with(&|v| v["text"] = json!("  ")), 422, "empty prompt"),
        ("POST", "/api/sample", vec![], with(&|v| v["text"] = json!(long)), 422, "characters"),
        ("POST", "/api/sample", vec![], with(&|v| v["length"] = json!(1000)), 422, "max_frames"),
        ("POST", "/api/sample", vec![], with(&|v| v["length"] = json!(0)), 422, "length"),
        ("POST", "/api/sample", vec![], with(&|v| v["steps"] = json!(0)), 422, "steps"),
        ("POST", "/api/sample", vec![], with(&|v| v["steps"] = json!(5000)), 422, "steps"),
        (
            "POST",
            "/api/sample",
            vec![],
            with(&|v| v["kf_guidance"] = json!(-1)),
            422,
            "kf_guidance",
        ),
        (
            "POST",
            "/api/sample",
            vec![],
            with(&|v| v["text_guidance"] = json!(-1)),
            422,
            "text_guidance",
        ),
        // The test model was trained without text drop: no text-free branch to guide against.
        (
            "POST",
            "/api/sample",
            vec![],
            with(&|v| v["text_guidance"] = json!(2.5)),
            422,
            "text_drop_prob",
        ),
        (
            "POST",
            "/api/sample",
            vec![],
            with(&|v| v["transition_guidance"] = json!(1e9)),
            422,
            "transition_guidance",
        ),
        (
            "POST",
            "/api/sample",
            vec![],
            key(json!({"frame": 60, "root": [0, 0.9, 1]})),
            422,
            "beyond the length",
        ),
        (
            "POST",
            "/api/sample",
            vec![],
            key(json!({"frame": 3, "joints": [[0, 1, 0]]})),
            422,
            "22 joints",
        ),
        (
            "POST",
            "/api/sample",
            vec![],
            key(json!({"frame": 3, "root": [1e300, 0.9, 0]})),
            422,
            "finite metres",
        ),
        ("POST", "/api/sample", vec![], key(json!({"frame": 3})), 422, "needs"),
        (
            "POST",
            "/api/sample",
            vec![],
            with(
                &|v| v["keyframes"] = json!({"keyframes": (0..300).map(|f| json!({"frame": f, "heading": 0})).collect::<Vec<_>>()}),
            ),
            422,
            "at most",
        ),
        ("POST", "/api/sample", vec![], big, 413, "length limit"),
        ("GET", "/api/sample", vec![], String::new(), 405, "/api/sample"),
        ("POST", "/api/export?format=gif", vec![], ok.to_string(), 400, "format"),
        (
            "POST",
            "/api/suggest",
            vec![],
            json!({"request": ok, "count": 0}).to_string(),
            422,
            "count",
        ),
        (
            "POST",
            "/api/suggest",
            vec![],
            json!({"request": ok, "strategy": "best"}).to_string(),
            422,
            "strategy",
        ),
        (
            "POST",
            "/api/import?name=x.npy",
            vec![("Content-Type", "application/octet-stream")],
            "not an npy".into(),
            422,
            "x.npy",
        ),
        (
            "POST",
            "/api/import?name=x.bvh",
            vec![("Content-Type", "application/octet-stream")],
            "HIERARCHY\nJOINT".into(),
            422,
            "x.bvh",
        ),
        ("POST", "/api/import?name=x.bvh", vec![], "{}".into(), 415, "octet-stream"),
        ("GET", "/api/nothing", vec![], String::new(), 404, "no such page"),
    ];
    for (method, path, headers, body, status, word) in &cases {
        let r = http(a, method, path, headers, body.as_bytes());
        let text = String::from_utf8_lossy(&r.body).to_string();
        assert_eq!(r.status, *status, "{method} {path} {headers:?} {:.80}: {text}", body);
        let e = r.error();
        assert!(e.contains(word) && !e.contains('\n'), "{path} {body:.60}: '{e}' lacks '{word}'");
    }
    // The server still serves after all of that.
    assert_eq!(post(a, "/api/sample", &ok).status, 200);
    srv.stop().unwrap();
}

/// One generation at a time: with no waiting place, a request that arrives while another runs
/// is answered 503 at once, and the running one completes. On a loaded machine the slow request
/// can finish before a status poll sees it running; it is then sent again with more steps.
#[test]
fn a_full_queue_answers_503() {
    let Some(srv) = server(0) else { return };
    let a = srv.addr;
    let max_steps =
        http(a, "GET", "/api/status", &[], b"").json()["limits"]["max_steps"].as_u64().unwrap();
    for steps in [300, max_steps, max_steps] {
        let slow = std::thread::spawn(move || {
            post(
                a,
                "/api/sample",
                &json!({"text": "a person walks.", "length": 196, "steps": steps}),
            )
        });
        let t0 = std::time::Instant::now();
        while http(a, "GET", "/api/status", &[], b"").json()["pending"] == 0 && !slow.is_finished()
        {
            assert!(t0.elapsed().as_secs() < 60, "the slow request never started");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        if slow.is_finished() {
            assert_eq!(slow.join().unwrap().status, 200);
            continue;
        }
        let r = post(a, "/api/sample", &json!({"text": "a person runs.", "length": 20}));
        assert_eq!(r.status, 503, "{}", String::from_utf8_lossy(&r.body));
        assert!(r.error().contains("busy"));
        assert_eq!(slow.join().unwrap().status, 200);
        srv.stop().unwrap();
        return;
    }
    panic!("every slow request finished before a status poll saw it running");
}

fn numbers(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Exported features and joints are `.npy` files of the motion; features read back through
/// the upload give the same joints; the BVH reads back as a motion one frame shorter.
#[test]
fn exports_read_back() {
    let Some(srv) = server(4) else { return };
    let a = srv.addr;
    let req = json!({"text": "a person waves.", "length": 50, "seed": 9});
    let m = post(a, "/api/sample", &req).json();
    let joints = |path: &str| -> Vec<f64> {
        let r = post(a, path, &req);
        assert_eq!(r.status, 200);
        let arr = diffkfc_data::io::npy::decode_f64(std::path::Path::new(path), &r.body).unwrap().0;
        assert_eq!(
            arr.shape,
            if path.contains("joints") { vec![50, 22, 3] } else { vec![50, 263] }
        );
        arr.data
    };
    let j = joints("/api/export?format=joints");
    let sample: Vec<f64> = numbers(&m["joints"]);
    let worst = max_diff(&j, &sample);
    assert!(worst < 1e-3, "exported joints differ from the sample by {worst}");
    let feats = post(a, "/api/export?format=features", &req);
    let up = http(
        a,
        "POST",
        "/api/import?name=m.npy",
        &[("Content-Type", "application/octet-stream")],
        &feats.body,
    );
    assert_eq!(up.status, 200, "{}", String::from_utf8_lossy(&up.body));
    let u = up.json();
    let worst = max_diff(&numbers(&u["joints"]), &sample);
    assert!(worst < 1e-3, "features read back differ by {worst} m");
    let bvh = post(a, "/api/export?format=bvh", &req);
    assert!(bvh
        .headers
        .iter()
        .any(|(k, v)| k == "content-disposition" && v.contains("motion.bvh")));
    let up = http(
        a,
        "POST",
        "/api/import?name=m.bvh",
        &[("Content-Type", "application/octet-stream")],
        &bvh.body,
    );
    assert_eq!(up.status, 200, "{}", String::from_utf8_lossy(&up.body));
    assert_eq!(up.json()["length"], 49);
    srv.stop().unwrap();
}
