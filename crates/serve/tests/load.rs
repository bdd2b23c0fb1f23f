//! Load on loopback: 8 clients send 50 keyed requests each at once. Every request succeeds (the
//! queue holds them all; nothing is refused), latencies are reported (p50, p99), and the
//! server's memory is flat: the resident set after the second half stays within 64 MiB of the
//! one after the first.

mod common;
use common::*;
use serde_json::json;

const CLIENTS: usize = 8;
const REQUESTS: usize = 50;

/// Resident memory of this process (the server runs in it), in KiB (Linux).
fn rss_kib() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find(|l| l.starts_with("VmRSS:"))?.split_whitespace().nth(1)?.parse().ok()
}

fn round(addr: std::net::SocketAddr, half: usize) -> Vec<f64> {
    let workers: Vec<_> = (0..CLIENTS)
        .map(|c| {
            std::thread::spawn(move || {
                (0..REQUESTS / 2)
                    .map(|i| {
                        let n = (c * REQUESTS + half * REQUESTS / 2 + i) as f64;
                        let body = json!({
                            "text": "a person walks forward.",
                            "seed": n as u64,
                            "keyframes": {"length": 60, "keyframes": [
                                {"frame": 0, "root": [0.0, 0.9, 0.0], "heading": 0},
                                {"frame": 30, "root": [0.1 * (n % 5.0), 0.9, 1.2], "heading": 10},
                                {"frame": 59, "root": [0.0, 0.9, 2.4]}]}
                        });
                        let t0 = std::time::Instant::now();
                        let r = post(addr, "/api/sample", &body);
                        assert_eq!(
                            r.status,
                            200,
                            "client {c} request {i}: {}",
                            String::from_utf8_lossy(&r.body)
                        );
                        let place = r.json()["metrics"]["place_err_m"].as_f64().unwrap();
                        assert!(place < 0.01, "place missed by {place} m");
                        t0.elapsed().as_secs_f64() * 1e3
                    })
                    .collect::<Vec<f64>>()
            })
        })
        .collect();
    workers.into_iter().flat_map(|w| w.join().unwrap()).collect()
}

#[test]
fn eight_clients_fifty_requests_each() {
    let Some(srv) = server(16) else { return };
    let t0 = std::time::Instant::now();
    let mut ms = round(srv.addr, 0);
    let rss_half = rss_kib();
    ms.extend(round(srv.addr, 1));
    let rss_end = rss_kib();
    let secs = t0.elapsed().as_secs_f64();
    ms.sort_by(f64::total_cmp);
    let q = |p: f64| ms[((ms.len() - 1) as f64 * p).round() as usize];
    println!(
        "load: {} requests from {CLIENTS} clients in {secs:.1} s ({:.1}/s), latency p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms; RSS {:?} -> {:?} KiB",
        ms.len(),
        ms.len() as f64 / secs,
        q(0.5),
        q(0.99),
        ms[ms.len() - 1],
        rss_half,
        rss_end
    );
    assert_eq!(ms.len(), CLIENTS * REQUESTS);
    if let (Some(a), Some(b)) = (rss_half, rss_end) {
        assert!(b < a + 64 * 1024, "memory grew from {a} to {b} KiB over 200 requests");
    }
    let status = http(srv.addr, "GET", "/api/status", &[], b"").json();
    assert_eq!(status["pending"], 0, "{status}");
    srv.stop().unwrap();
}
